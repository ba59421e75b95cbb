"""The Chiang et al. hair/fur BSDF as Warp functions for the renderer's kernels.

Local frame (docs/MODEL.md, pbrt-v4): x along the fiber, z the surface normal at the hit, y = z × x;
sin θ = w.x, φ = atan2(w.z, w.y), used only as Δφ = φ_i − φ_o (`incident`). wo points toward the viewer,
wi toward the light, h ∈ [−1, 1] is the signed offset of the hit from the fiber axis.

Usage inside a kernel:
    setup = lobe_setup(coeffs, wo, h)          # everything that depends on wo and h only
    s_value = hair_value(setup, wi)            # S, the cosine-weighted BSDF (RGB)
    density = hair_pdf(setup, wi)              # solid-angle pdf of hair_sample
    s_value, density = hair_value_pdf(setup, wi)   # both from one evaluation of the lobes
    wi = hair_sample(setup, u)                 # u: three uniforms in [0, 1)
    d = hair_sample_incident(setup, u)         # the sample with its angles (d.w the direction), and
    s_value, density = hair_value_pdf_at(setup, d)  # its value and pdf without recovering them from d.w
Nothing allocates; everything is float32 but the azimuths (float64: `LobeSetup.phi_center`).
"""

import numpy as np
import warp as wp

from ..numerics import INV_TWO_PI, PI64, TWO_PI64, cos_from_sin
from .lobes import (
    attenuation,
    cone_constants,
    fresnel_dielectric,
    lobe_sum,
    logistic_norm,
    logistic_tail,
    longitudinal_norm,
    longitudinal_scattering,
    mat43,
    sample_longitudinal_sin,
    sample_trimmed_logistic,
    trimmed_logistic,
    wrap_angle,
)
from .params import HairParams, lobe_variances, logistic_scale


@wp.struct
class HairCoefficients:
    """What the kernels need of a HairParams: derived once per material on the host (float64 → float32)."""

    sigma_a: wp.vec3  # absorption per unit fiber radius, RGB
    eta: float
    inv_v: wp.vec4  # 1 / the longitudinal variance of R, TT, TRT, residual
    m_norm: wp.vec4  # longitudinal_norm(v)
    cone: wp.mat44  # cone_constants(v), a row per lobe (sampling only)
    s: float  # logistic scale of the azimuthal lobes
    inv_s: float
    n_norm: float  # logistic_norm(s)
    n_tail: float  # logistic_tail(s)
    sin_2k_alpha: wp.vec3  # sin(α), sin(2α), sin(4α)
    cos_2k_alpha: wp.vec3


def hair_coefficients(params: HairParams) -> HairCoefficients:
    return coefficients_from(params.absorption, params.eta, params.lobe_variances, params.logistic_scale, params.alpha)


def strand_coefficients(params: HairParams, looks) -> np.ndarray:
    """Each strand's HairCoefficients (model/variation.py's StrandLooks: its σ_a, β_m and β_n), as a NumPy
    structured array (`wp.array(..., dtype=HairCoefficients)` takes it)."""
    v = lobe_variances(looks.beta_m, params.r_roughness_scale).T  # (S, 4)
    return coefficients_table(looks.sigma_a, params.eta, v, logistic_scale(looks.beta_n), params.alpha)


def coefficients_from(sigma_a, eta, v, s, alpha) -> HairCoefficients:
    """The coefficients of σ_a (RGB), η, the lobes' variances v [R, TT, TRT, residual], the logistic scale s and
    the tilt α (degrees)."""
    row = coefficients_table(np.atleast_2d(sigma_a), eta, np.atleast_2d(v), np.atleast_1d(s), alpha)[0]
    c = HairCoefficients()
    for name in row.dtype.names:
        setattr(c, name, row[name])
    return c


def coefficients_table(sigma_a, eta, v, s, alpha) -> np.ndarray:
    """HairCoefficients of N materials or strands as a NumPy structured array of `HairCoefficients.numpy_dtype()`:
    σ_a (N, 3), v (N, 4), s (N,); η and α shared. The per-lobe normalisations are formed here once, in float64,
    and rounded once to the kernels' float32."""
    table = np.zeros(len(s), dtype=HairCoefficients.numpy_dtype())
    table["sigma_a"] = sigma_a
    table["eta"] = eta
    table["inv_v"] = 1.0 / v
    table["m_norm"] = longitudinal_norm(v)
    table["cone"] = cone_constants(v)
    table["s"] = s
    table["inv_s"] = 1.0 / s
    table["n_norm"] = logistic_norm(s)
    table["n_tail"] = logistic_tail(s)
    angles = np.radians(alpha) * np.array([1.0, 2.0, 4.0])
    table["sin_2k_alpha"] = np.sin(angles)
    table["cos_2k_alpha"] = np.cos(angles)
    return table


@wp.struct
class LobeSetup:
    """The wo- and h-dependent half of the model, shared by value, pdf and sample."""

    sin_o: wp.vec4  # sin θ_o tilted per lobe (R: θ_o + 2α, TT: θ_o − α, TRT: θ_o − 4α, residual: θ_o)
    cos_o: wp.vec4  # |cos| of the same angles
    azimuth_o: wp.vec2d  # (cos φ_o, sin φ_o)
    phi_center: wp.vec3d  # Φ(p) = 2pγ_t − 2γ_o + pπ, the azimuthal centre of R, TT, TRT
    A: mat43  # attenuation per lobe (rows), RGB
    prob: wp.vec4  # lobe selection probabilities ∝ channel mean of A_p
    c: HairCoefficients


@wp.func
def lobe_setup(c: HairCoefficients, wo: wp.vec3, h: float):
    sin_o = wp.clamp(wo[0], -1.0, 1.0)
    cos_o = cos_from_sin(sin_o)
    h = wp.clamp(h, -1.0, 1.0)

    # Refraction: θ_t by Snell, γ_t in the normal plane with the Bravais index η' (docs/MODEL.md); the form
    # h cos θ_o / sqrt(η² − sin² θ_o) = h / η' has no division by cos θ_o. An η within float32 rounding of 1
    # makes both square roots 0 at grazing: the floors give the η → 1⁺ limits there (γ_t = 0, an infinitely
    # long path that transmits nothing unless σ_a = 0) instead of 0/0. For η > 1 they change nothing.
    sin_t = sin_o / c.eta
    cos_t = wp.max(cos_from_sin(sin_t), 1.0e-37)
    sin_gamma_t = wp.clamp(h * cos_o / wp.max(wp.sqrt(c.eta * c.eta - sin_o * sin_o), 1.0e-37), -1.0, 1.0)
    cos_gamma_t = cos_from_sin(sin_gamma_t)
    T = wp.vec3(
        wp.exp(-c.sigma_a[0] * 2.0 * cos_gamma_t / cos_t),
        wp.exp(-c.sigma_a[1] * 2.0 * cos_gamma_t / cos_t),
        wp.exp(-c.sigma_a[2] * 2.0 * cos_gamma_t / cos_t),
    )
    f = fresnel_dielectric(cos_o * cos_from_sin(h), c.eta)

    L = LobeSetup()
    L.A = attenuation(f, T)
    mean_a = wp.vec4(0.0)
    for p in range(4):
        mean_a[p] = (L.A[p, 0] + L.A[p, 1] + L.A[p, 2]) / 3.0
    L.prob = mean_a / (mean_a[0] + mean_a[1] + mean_a[2] + mean_a[3])

    # Cuticle tilt (docs/MODEL.md "Cuticle tilt α"): the scales' normals lean toward the root (−x) by α, so R
    # mirrors about θ_o + 2α (its peak moves toward the root) and the refracted lobes the other way: TT about
    # θ_o − α, TRT about θ_o − 4α. pbrt-v4 and Mitsuba 3 rotate the opposite way. |cos| keeps the rotated
    # angle in [−π/2, π/2] when the rotation passes the pole.
    sa = c.sin_2k_alpha
    ca = c.cos_2k_alpha
    L.sin_o = wp.vec4(
        sin_o * ca[1] + cos_o * sa[1], sin_o * ca[0] - cos_o * sa[0], sin_o * ca[2] - cos_o * sa[2], sin_o
    )
    L.cos_o = wp.vec4(
        wp.abs(cos_o * ca[1] - sin_o * sa[1]),
        wp.abs(cos_o * ca[0] + sin_o * sa[0]),
        wp.abs(cos_o * ca[2] + sin_o * sa[2]),
        cos_o,
    )
    # The azimuthal centres are formed in float64: a narrow logistic (s ≈ 2e-3 at β_n = 0) turns the
    # float32 rounding of atan2, asin and the 2π wrap (~1e-6 rad) into a 1e-3 relative error of N_p.
    sin_o_d = wp.float64(sin_o)
    cos_o_d = wp.sqrt(wp.max(wp.float64(0.0), (wp.float64(1.0) - sin_o_d) * (wp.float64(1.0) + sin_o_d)))
    eta_d = wp.float64(c.eta)
    h_d = wp.float64(h)
    gamma_o = wp.asin(h_d)
    q_d = wp.max(wp.sqrt(eta_d * eta_d - sin_o_d * sin_o_d), wp.float64(1.0e-37))
    gamma_t = wp.asin(wp.clamp(h_d * cos_o_d / q_d, wp.float64(-1.0), wp.float64(1.0)))
    # φ_o as a unit vector: Δφ is then one atan2 of a cross and a dot product (`incident_angles`), and a sample's
    # φ_i one rotation of it, where an angle would cost an atan2 more per vertex.
    y_o = wp.float64(wo[1])
    z_o = wp.float64(wo[2])
    r_o = wp.sqrt(y_o * y_o + z_o * z_o)
    if r_o > wp.float64(0.0):
        L.azimuth_o = wp.vec2d(y_o / r_o, z_o / r_o)
    else:  # along the fiber: φ_o = atan2(±0, ±0), 0 or ±π by the zeros' signs
        phi_o = wp.atan2(z_o, y_o)
        L.azimuth_o = wp.vec2d(wp.cos(phi_o), wp.sin(phi_o))
    L.phi_center = wp.vec3d(
        wp.float64(-2.0) * gamma_o,
        wp.float64(2.0) * gamma_t - wp.float64(2.0) * gamma_o + PI64,
        wp.float64(4.0) * gamma_t - wp.float64(2.0) * gamma_o + wp.float64(2.0) * PI64,
    )
    L.c = c
    return L


@wp.struct
class Incident:
    """A local direction wi and the angles the lobes read of it: sin θ_i, cos θ_i and Δφ = φ_i − φ_o (float64, up
    to a multiple of 2π). A sample carries the angles it was built from, so evaluating it costs no atan2."""

    w: wp.vec3
    sin_i: float
    cos_i: float
    dphi: wp.float64


@wp.func
def incident_angles(L: LobeSetup, wi: wp.vec3):
    """(sin θ_i, cos θ_i, Δφ) of a local direction: Δφ in float64 from the cross and dot products of the two
    azimuths, as exact as the inputs (the difference of two atan2 would round twice)."""
    sin_i = wp.clamp(wi[0], -1.0, 1.0)
    y = wp.float64(wi[1])
    z = wp.float64(wi[2])
    a = L.azimuth_o
    dphi = wp.atan2(a[0] * z - a[1] * y, a[0] * y + a[1] * z)
    if y == wp.float64(0.0) and z == wp.float64(0.0):
        # Along the fiber φ_i is atan2(±0, ±0), 0 or ±π by the zeros' signs, as φ = atan2(w.z, w.y) defines it.
        dphi = wp.atan2(z, y) - wp.atan2(a[1], a[0])
    return sin_i, cos_from_sin(sin_i), dphi


@wp.func
def incident(L: LobeSetup, wi: wp.vec3):
    """The Incident of a local direction (`incident_angles`)."""
    d = Incident()
    d.w = wi
    sin_i, cos_i, dphi = incident_angles(L, wi)
    d.sin_i = sin_i
    d.cos_i = cos_i
    d.dphi = dphi
    return d


@wp.func
def lobe_densities(L: LobeSetup, sin_i: float, cos_i: float, dphi: wp.float64):
    """M_p N_p for each lobe (N_3 = 1/2π): the solid-angle density each lobe would sample alone."""
    d = wp.vec4(0.0)
    for p in range(3):
        m = longitudinal_scattering(sin_i, cos_i, L.sin_o[p], L.cos_o[p], L.c.inv_v[p], L.c.m_norm[p])
        d[p] = m * trimmed_logistic(float(wrap_angle(dphi - L.phi_center[p])), L.c.inv_s, L.c.n_norm)
    d[3] = longitudinal_scattering(sin_i, cos_i, L.sin_o[3], L.cos_o[3], L.c.inv_v[3], L.c.m_norm[3]) * INV_TWO_PI
    return d


@wp.func
def hair_value(L: LobeSetup, wi: wp.vec3):
    """S(wo, wi, h) = Σ_p A_p M_p N_p, the cosine-weighted BSDF (pbrt's f times |cos θ_i|, Mitsuba's eval)."""
    value, _density = hair_value_pdf(L, wi)
    return value


@wp.func
def hair_pdf(L: LobeSetup, wi: wp.vec3):
    _value, density = hair_value_pdf(L, wi)
    return density


@wp.func
def hair_value_pdf(L: LobeSetup, wi: wp.vec3):
    """(S, pdf) at wi from one evaluation of the lobes: what a path tracer needs at every vertex.

    The angles go as a tuple, not an Incident: Warp's reverse mode, which tests/helpers/bsdf_grad.py runs through
    this function, differentiated the assignments to an Incident's fields wrongly (tests/test_bsdf_grad.py).
    """
    sin_i, cos_i, dphi = incident_angles(L, wi)
    d = lobe_densities(L, sin_i, cos_i, dphi)
    return lobe_sum(L.A, d), wp.dot(L.prob, d)


@wp.func
def hair_value_pdf_at(L: LobeSetup, wi: Incident):
    """`hair_value_pdf` toward an Incident, from its angles: a sample's are those it was built from."""
    d = lobe_densities(L, wi.sin_i, wi.cos_i, wi.dphi)
    return lobe_sum(L.A, d), wp.dot(L.prob, d)


@wp.func
def choose_lobe(prob: wp.vec4, u: float):
    """The lobe whose interval of [0, 1) holds u (lobes in order R, TT, TRT, residual), and where in it.

    In the upper half the intervals are located from the top with 1 − u, which is exact there: the
    residual lobe's probability can be 1e-8 (dark hair), finer than float32 cumulative sums near 1 resolve.
    """
    p = int(0)
    u_rot = float(0.0)
    if u < 0.5:
        p = 3
        lo = float(0.0)
        for q in range(3):
            if p == 3 and u < lo + prob[q]:
                p = q
                u_rot = (u - lo) / prob[q]
            lo += prob[q]
        if p == 3:
            u_rot = (u - lo) / prob[3]
    else:
        t = 1.0 - u
        hi = float(0.0)
        found = bool(False)
        for k in range(3):
            q = 3 - k
            if not found and t <= hi + prob[q]:
                found = True
                p = q
                u_rot = 1.0 - (t - hi) / prob[q]
            hi += prob[q]
        if not found:
            u_rot = 1.0 - (t - hi) / prob[0]
    return p, wp.clamp(u_rot, 0.0, 1.0)


@wp.func
def hair_sample_incident(L: LobeSetup, u: wp.vec3):
    """An Incident drawn exactly from hair_pdf: lobe by u[0], then M_p by u[1] and N_p by u[2]; its angles are
    those the direction was built from.

    The remainder of u[0] after the lobe choice drives the rotation about the longitudinal cone, where an
    error in it moves wi linearly; reusing it for the logistic azimuth (as pbrt does) would amplify its
    float32 rounding in the logistic's tails.
    """
    p, u_rot = choose_lobe(L.prob, u[0])
    sin_i, cos_i = sample_longitudinal_sin(u[1], u_rot, L.sin_o[p], L.cos_o[p], L.c.cone[p])
    d = Incident()
    d.sin_i = sin_i
    d.cos_i = cos_i
    dphi = TWO_PI64 * wp.float64(u[2])
    if p < 3:
        dphi = L.phi_center[p] + wp.float64(sample_trimmed_logistic(u[2], L.c.s, L.c.n_tail))
    d.dphi = wrap_angle(dphi)
    # φ_i = φ_o + Δφ, by rotating φ_o's unit vector. Δφ is wrapped to [−π, π) in float64 first, so that float32's
    # cos and sin round it by about 1e-7 rad, as the float32 direction they build rounds anyway.
    x = float(d.dphi)
    c = wp.float64(wp.cos(x))
    s = wp.float64(wp.sin(x))
    a = L.azimuth_o
    d.w = wp.vec3(d.sin_i, d.cos_i * float(a[0] * c - a[1] * s), d.cos_i * float(a[1] * c + a[0] * s))
    return d


@wp.func
def hair_sample(L: LobeSetup, u: wp.vec3):
    """The direction of `hair_sample_incident`."""
    return hair_sample_incident(L, u).w
