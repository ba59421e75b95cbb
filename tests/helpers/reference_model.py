"""Independent float64 NumPy reference of the Chiang et al. (2015/2016) hair BSDF.

Written from /work/shared/reference/MODEL.md (pbrt-v4 frame) and the project's fixed
conventions only, never from the Warp code it tests.  Everything is float64 and vectorized
over N directions.  Lobe order everywhere: [R, TT, TRT, residual] (p = 0..3).
"""

import numpy as np
from scipy.special import i0e

_EU = np.array([0.419, 0.697, 1.37])  # docs/MODEL.md "From artist controls": eumelanin
_PHEO = np.array([0.187, 0.4, 1.05])  # ... and pheomelanin absorption per unit radius
_BETA_MIN = 0.01  # project convention: roughness floor


def _rgb(x):
    return np.broadcast_to(np.asarray(x, dtype=np.float64), (3,)).copy()


def coefficients(controls):
    """Artist controls -> sigma_a, eta, per-lobe v, logistic scale s, alpha (radians)."""
    c = {k: v for k, v in controls.items() if v is not None}
    bm = max(float(c.get("beta_m", 0.3)), _BETA_MIN)
    bn = max(float(c.get("beta_n", 0.3)), _BETA_MIN)
    kinds = [k for k in ("albedo", "sigma_a") if k in c]
    if "eumelanin" in c or "pheomelanin" in c:
        kinds.append("melanin")
    if len(kinds) != 1:
        raise ValueError(f"need exactly one colour control, got {kinds}")
    if kinds[0] == "albedo":
        # Albedo inversion (talk, Controllability; docs/MODEL.md), using the floored beta_n; an "albedo_inversion"
        # entry (p_0 ... p_5) replaces the talk's polynomial.
        if "albedo_inversion" in c:
            poly = sum(float(p) * bn**k for k, p in enumerate(c["albedo_inversion"]))
        else:
            poly = 5.969 - 0.215 * bn + 2.532 * bn**2 - 10.73 * bn**3 + 5.574 * bn**4 + 0.245 * bn**5
        sigma_a = (np.log(_rgb(c["albedo"])) / poly) ** 2
    elif kinds[0] == "sigma_a":
        sigma_a = _rgb(c["sigma_a"])
    else:  # d'Eon 2011 melanin coefficients (docs/MODEL.md)
        sigma_a = float(c.get("eumelanin", 0.0)) * _EU + float(c.get("pheomelanin", 0.0)) * _PHEO
    # Longitudinal variance (docs/MODEL.md "Roughness mappings"); R scaled by the species factor.
    v = (0.726 * bm + 0.812 * bm**2 + 3.7 * bm**20) ** 2
    v_lobes = np.array([v * float(c.get("r_roughness_scale", 1.0)), 0.25 * v, 4.0 * v, 4.0 * v])
    # Azimuthal logistic scale, with pbrt/Mitsuba/Cycles' sqrt(pi/8) factor.
    s = np.sqrt(np.pi / 8.0) * (0.265 * bn + 1.194 * bn**2 + 5.372 * bn**22)
    return {
        "sigma_a": sigma_a,
        "eta": float(c.get("eta", 1.55)),
        "v": v_lobes,
        "s": float(s),
        "alpha": np.deg2rad(float(c.get("alpha", 2.0))),
    }


def _angles(w):
    """sin theta = w.x, cos theta = sqrt(1 - sin^2), phi = atan2(w.z, w.y) (docs/MODEL.md "Frame")."""
    w = np.asarray(w, dtype=np.float64)
    sin_t = np.clip(w[:, 0], -1.0, 1.0)
    return sin_t, np.sqrt(np.maximum(0.0, 1.0 - sin_t**2)), np.arctan2(w[:, 2], w[:, 1])


def _fiber(co, wo, h):
    """Per-hit quantities that depend on wo and h only: A_p (N,4,3), gamma_o, gamma_t."""
    h = np.clip(np.asarray(h, dtype=np.float64), -1.0, 1.0)
    sin_o, cos_o, _ = _angles(wo)
    eta = co["eta"]
    # docs/MODEL.md "Refraction": sin gamma_t = h / eta', eta' = sqrt(eta^2 - sin^2 theta_o) / cos theta_o.
    # Written as h cos / sqrt(.) so that cos theta_o = 0 gives 0 instead of h / inf.
    sin_gt = h * cos_o / np.sqrt(eta**2 - sin_o**2)
    cos_gt = np.sqrt(np.maximum(0.0, 1.0 - sin_gt**2))
    cos_tt = np.sqrt(1.0 - (sin_o / eta) ** 2)  # eta > 1: never zero
    T = np.exp(-co["sigma_a"][None, :] * (2.0 * cos_gt / cos_tt)[:, None])  # (N,3)
    # Unpolarized dielectric Fresnel at cos_i = cos theta_o sqrt(1 - h^2), entering index eta.
    ci = cos_o * np.sqrt(np.maximum(0.0, 1.0 - h**2))
    ct = np.sqrt(np.maximum(0.0, 1.0 - (1.0 - ci**2) / eta**2))
    r_par = (eta * ci - ct) / (eta * ci + ct)
    r_perp = (ci - eta * ct) / (ci + eta * ct)
    f = (0.5 * (r_par**2 + r_perp**2))[:, None]
    # docs/MODEL.md "The lobes": A0..A3; A3 sums the geometric series of all paths after TRT.
    A = np.empty((len(h), 4, 3))
    A[:, 0] = np.broadcast_to(f, T.shape)
    A[:, 1] = (1.0 - f) ** 2 * T
    A[:, 2] = A[:, 1] * T * f
    den = 1.0 - f * T
    with np.errstate(divide="ignore", invalid="ignore"):
        A[:, 3] = np.where(den > 0.0, A[:, 2] * f * T / np.where(den > 0.0, den, 1.0), 0.0)
    return A, np.arcsin(h), np.arcsin(sin_gt)


def _tilted(co, wo):
    """Cuticle tilt (docs/MODEL.md): theta_o + 2a (R), - a (TT), - 4a (TRT), unchanged (residual): the scales'
    normals lean toward the root (-x), so R moves toward the root. Returns sin theta_o' and |cos theta_o'|, each
    (N,4)."""
    sin_o, cos_o, _ = _angles(wo)
    d = co["alpha"] * np.array([2.0, -1.0, -4.0, 0.0])
    sin_p = sin_o[:, None] * np.cos(d) + cos_o[:, None] * np.sin(d)
    cos_p = np.abs(cos_o[:, None] * np.cos(d) - sin_o[:, None] * np.sin(d))
    return sin_p, cos_p


def _M(sin_i, cos_i, sin_o, cos_o, v):
    """d'Eon's M in log space (docs/MODEL.md "Longitudinal M_p"), safe for any v > 0:
    log I0(x) = log i0e(x) + x, and log(2 v sinh(1/v)) = log v + 1/v + log(1 - e^(-2/v)).
    The x and 1/v terms are combined as (cos_i cos_o - sin_i sin_o - 1) / v <= 0."""
    x = cos_i * cos_o / v
    log_m = np.log(i0e(x)) + (cos_i * cos_o - sin_i * sin_o - 1.0) / v - np.log(v) - np.log(-np.expm1(-2.0 / v))
    return np.exp(log_m)


def _Phi(p, gamma_o, gamma_t):
    return 2.0 * p * gamma_t - 2.0 * gamma_o + p * np.pi


def _trimmed_logistic(x, s):
    """Logistic(s) on [-pi, pi] (docs/MODEL.md "Azimuthal N_p"); CDF(pi) - CDF(-pi) = tanh(pi / 2s)."""
    e = np.exp(-np.abs(x) / s)
    return e / (s * (1.0 + e) ** 2) / np.tanh(np.pi / (2.0 * s))


def lobe_terms(co, wo, wi, h):
    """(M_p N_p (N,4), A (N,4,3)): the per-lobe geometry and attenuation."""
    A, g_o, g_t = _fiber(co, wo, h)
    sin_i, cos_i, phi_i = _angles(wi)
    phi_o = _angles(wo)[2]
    sin_p, cos_p = _tilted(co, wo)
    MN = _M(sin_i[:, None], cos_i[:, None], sin_p, cos_p, co["v"][None, :])
    dphi = phi_i - phi_o
    for p in range(3):
        x = np.mod(dphi - _Phi(p, g_o, g_t) + np.pi, 2.0 * np.pi) - np.pi  # wrap to [-pi, pi)
        MN[:, p] *= _trimmed_logistic(x, co["s"])
    MN[:, 3] /= 2.0 * np.pi  # isotropic residual
    return MN, A


def lobe_probs(A):
    """prob_p = mean_RGB(A_p) / sum_p mean_RGB(A_p) (project convention)."""
    m = A.mean(axis=2)
    tot = m.sum(axis=1, keepdims=True)
    return np.where(tot > 0.0, m / np.where(tot > 0.0, tot, 1.0), 0.0)


def attenuation(controls, wo, h):
    return _fiber(coefficients(controls), wo, h)[0]


def eval_lobes(controls, wo, wi, h):
    MN, A = lobe_terms(coefficients(controls), wo, wi, h)
    return MN[:, :, None] * A


def eval(controls, wo, wi, h):
    return eval_lobes(controls, wo, wi, h).sum(axis=1)


def pdf(controls, wo, wi, h):
    MN, A = lobe_terms(coefficients(controls), wo, wi, h)
    return (lobe_probs(A) * MN).sum(axis=1)


def sample(controls, wo, h, u):
    co = coefficients(controls)
    wo = np.asarray(wo, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    n = len(wo)
    A, g_o, g_t = _fiber(co, wo, h)
    prob = lobe_probs(A)
    # 1. Lobe choice: smallest p with u0 < cdf_{p+1}; fallback to the last lobe with prob > 0.
    cdf = np.concatenate([np.zeros((n, 1)), np.cumsum(prob, axis=1)], axis=1)  # (N,5)
    below = u[:, :1] < cdf[:, 1:]
    last_pos = 3 - np.argmax(prob[:, ::-1] > 0.0, axis=1)
    p = np.where(below.any(axis=1), np.argmax(below, axis=1), last_pos)
    rows = np.arange(n)
    pp = prob[rows, p]
    with np.errstate(divide="ignore", invalid="ignore"):
        u_r = np.clip(np.where(pp > 0.0, (u[:, 0] - cdf[rows, p]) / pp, 0.0), 0.0, 1.0)
    # 2. Longitudinal (docs/MODEL.md "Sampling" 3): t = 1 - cos theta.  ln(u + (1-u) e^(-2/v)) = ln(1 - x)
    # with x = (1-u)(1 - e^(-2/v)): log1p(-x) where x is small (no cancellation at large v), the direct
    # form where x is near 1 (there 1 - x would lose the e^(-2/v) that sets the far tail).
    sin_p, cos_p = _tilted(co, wo)
    sin_o, cos_o, v = sin_p[rows, p], cos_p[rows, p], co["v"][p]
    u1 = u[:, 1]
    x = -(1.0 - u1) * np.expm1(-2.0 / v)
    with np.errstate(divide="ignore"):
        lg = np.where(x < 0.5, np.log1p(-np.minimum(x, 0.5)), np.log(u1 + (1.0 - u1) * np.exp(-2.0 / v)))
    t = np.minimum(-v * np.maximum(lg, -2.0 / v), 2.0)
    cos_t = 1.0 - t
    sin_t = np.sqrt(np.maximum(0.0, t * (2.0 - t)))
    sin_i = np.clip(-cos_t * sin_o + sin_t * np.cos(2.0 * np.pi * u_r) * cos_o, -1.0, 1.0)
    cos_i = np.sqrt(1.0 - sin_i**2)
    # 3. Azimuth: inverse CDF of the trimmed logistic, x = s logit(q), q = u k + CDF(-pi),
    # k = CDF(pi) - CDF(-pi); 1 - q = (1-u) k + CDF(-pi) by symmetry (no cancellation).
    s = co["s"]
    c_lo = 1.0 / (1.0 + np.exp(np.pi / s)) if np.pi / s < 700.0 else 0.0
    k = np.tanh(np.pi / (2.0 * s))
    u2 = u[:, 2]
    with np.errstate(divide="ignore"):
        x = s * (np.log(u2 * k + c_lo) - np.log((1.0 - u2) * k + c_lo))
    x = np.clip(x, -np.pi, np.pi)
    dphi = np.where(p < 3, _Phi(p, g_o, g_t) + x, 2.0 * np.pi * u2)
    phi_i = _angles(wo)[2] + dphi
    wi = np.stack([sin_i, cos_i * np.cos(phi_i), cos_i * np.sin(phi_i)], axis=1)
    # 4. pdf and weight from the full formulas at the sampled direction.
    MN, A = lobe_terms(co, wo, wi, h)
    pd = (prob * MN).sum(axis=1)
    S = (MN[:, :, None] * A).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(pd[:, None] > 0.0, S / np.where(pd > 0.0, pd, 1.0)[:, None], 0.0)
    return wi, weight, pd
