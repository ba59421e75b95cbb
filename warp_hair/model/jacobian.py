"""∂S/∂θ of the hair BSDF in closed form, evaluated together with S: the gradient tracer's per-vertex derivative.

θ is laid out as in `warp_hair.controls` (colour[0:3], β_m, β_n, α in degrees, η, r_roughness_scale). Usage:

    derivs = coefficient_derivatives(params)       # host, once per material (float64 → float32)
    # in a kernel, at a fiber vertex:
    setup = lobe_setup(coeffs, wo, h)
    d_setup = lobe_setup_grad(setup, wo, h)          # the wo- and h-dependent derivatives, shared by every wi
    value, density, lobes = hair_value_pdf_lobes(setup, wi)     # wi an Incident: = hair_value_pdf_at(setup, wi), and
    J = hair_value_jacobian(setup, d_setup, derivs, lobes)      # ... J[c, k] = ∂S_c/∂θ_k there

S and pdf are those of `hair_value_pdf_at` (the same operations on the same values), so the gradient tracer follows
the renderer's paths, and J differentiates that same evaluation of the lobes. tests/helpers/bsdf_grad.py (Warp's
reverse mode through the model as written) is the independent check of J: tests/test_bsdf_jacobian.py.

Structure. S_c = Σ_p D_p A_pc with D_p = M_p N_p the same for every channel, so

    ∂S_c/∂θ_k = Σ_p D_p (A_pc ∂ln D_p/∂θ_k + ∂A_pc/∂θ_k),

and each control reaches few factors: β_m the variances v_p of every M_p (r_roughness_scale only R's), α the
tilted θ_o of M_R, M_TT, M_TRT, β_n the logistic scale s of N_R, N_TT, N_TRT (and σ_a, through the albedo
inversion), η the attenuation (Fresnel, the internal path length) and the azimuthal centres Φ_TT, Φ_TRT, the
colour only σ_a,c in A_pc. The map θ → (σ_a, v, s, α), its derivatives and those of the material's
normalisations (m_norm(v), n_norm(s)) depend on the material only: `coefficient_derivatives` forms them on the
host in float64. What depends on wo and h (∂A/∂σ_a, ∂A/∂η, ∂Φ_p/∂η, the tilt's sign) is `lobe_setup_grad`,
once per vertex; the log-derivatives of M_p and N_p in their own parameters come out of the evaluation of the
lobes (lobes.longitudinal_scattering_with_slopes, lobes.trimmed_logistic_with_slope), and
`hair_value_jacobian` combines them. The model's conventions carry over as wp.grad sees them: the |cos| of a
tilted θ_o that passed the pole flips the sign of its slope, the wrap of Δφ − Φ_p gives the slope of the side
it lands on, and the roughness floor (β ≤ 0.01 renders as 0.01) gives derivative 0, through the lobes and the
albedo inversion. Everything per vertex is float32, like S.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..controls import COLOUR_CONTROL_NAMES, CONTROLS, SCALAR_CONTROLS, THETA_SIZE, column
from ..numerics import INV_TWO_PI, cos_from_sin
from .hair_bsdf import Incident, LobeSetup
from .lobes import (
    attenuation_partials,
    fresnel_dielectric_d_eta,
    lobe_sum,
    longitudinal_scattering_with_slopes,
    mat43,
    trimmed_logistic_with_slope,
    wrap_angle,
)
from .params import (
    BETA_FLOOR,
    EUMELANIN_SIGMA_A,
    PHEOMELANIN_SIGMA_A,
    HairParams,
    albedo_denominator,
    lobe_variances,
    logistic_scale,
    longitudinal_variance,
)

wp.set_module_options({"enable_backward": False})

# θ as kernels carry it, and ∂S_c/∂θ_k (rows: channels of S).
controls_vec = wp.types.vector(length=THETA_SIZE, dtype=wp.float32)
value_jacobian_mat = wp.types.matrix(shape=(3, THETA_SIZE), dtype=wp.float32)
# The scalar controls whose columns hair_value_jacobian fills (after the colour's). A control added to the table
# without its derivative here stops the import, rather than fitting with a gradient of 0.
_DIFFERENTIATED = (
    "beta_m",
    "beta_n",
    "alpha",
    "eta",
    "r_roughness_scale",
    "color_spread",
    "roughness_spread",
    "tip_absorption",
    "tip_length",
)
if set(_DIFFERENTIATED) != set(SCALAR_CONTROLS):
    raise ImportError(f"model/jacobian.py differentiates {_DIFFERENTIATED}, the table has {SCALAR_CONTROLS}")
_COLOUR_COLUMNS = 3
assert all(k < _COLOUR_COLUMNS for name in COLOUR_CONTROL_NAMES for k in CONTROLS[name].columns)
(
    _BETA_M,
    _BETA_N,
    _ALPHA,
    _ETA,
    _R_ROUGHNESS_SCALE,
    _COLOR_SPREAD,
    _ROUGHNESS_SPREAD,
    _TIP_ABSORPTION,
    _TIP_LENGTH,
) = (column(name) for name in _DIFFERENTIATED)

# ∂θ_o,p/∂α of the tilted angles (R: θ_o + 2α, TT: θ_o − α, TRT: θ_o − 4α, residual: θ_o), per degree of α.
_TILT = wp.constant(wp.vec4(2.0 * math.pi / 180.0, -math.pi / 180.0, -4.0 * math.pi / 180.0, 0.0))


@wp.struct
class CoefficientDerivatives:
    """What the per-vertex derivative needs of one material, beyond its HairCoefficients."""

    d_sigma_d_colour: wp.mat33  # [c, k] = ∂σ_a,c/∂θ_k for the colour columns k = 0, 1, 2
    d_sigma_d_beta_n: wp.vec3  # the albedo inversion's dependence on β_n (0 for the other colour inputs)
    d_log_v_d_beta_m: float  # every lobe's v is a fixed multiple of v(β_m)
    d_log_v_r_d_scale: float  # 1 / r_roughness_scale: the R lobe's v only
    m_norm_log_slope: wp.vec4  # ∂ln m_norm_p/∂ln v_p
    d_log_s_d_beta_n: float
    n_norm_log_slope: float  # ∂ln n_norm/∂ln s
    # The variation's controls (model/variation.py); all 0 for a look without variation. The tip's are the
    # vertex's (`material.vertex_derivatives` fills them where the hit lies along its strand).
    d_sigma_d_color_spread: wp.vec3
    d_sigma_d_roughness_spread: wp.vec3
    d_log_v_d_roughness_spread: float
    d_log_s_d_roughness_spread: float
    d_sigma_d_tip_absorption: wp.vec3
    d_sigma_d_tip_length: wp.vec3


def _slope(mapping, x: float) -> float:
    """d mapping/dx at x by the complex step (exact to rounding: no difference is taken), so that the
    polynomial fits are differentiated from params.py's own definitions rather than restated here."""
    step = 1e-30
    return float(np.imag(mapping(complex(x, step)))) / step


def _live(beta: float) -> bool:
    """Whether β is above the roughness floor, where the mappings depend on it (at the floor: the floor's side,
    as wp.grad of max(β, floor) takes it)."""
    return beta > BETA_FLOOR


def coefficient_derivatives(params: HairParams) -> CoefficientDerivatives:
    """The material's CoefficientDerivatives, in float64 from the controls (HairParams), rounded once to float32."""
    mode = params.colour_input
    d_colour = np.zeros((3, 3))
    d_beta_n = np.zeros(3)
    if mode == "albedo":
        albedo = np.asarray(params.albedo, dtype=np.float64)

        def polynomial(beta_n):
            return albedo_denominator(beta_n, params.albedo_inversion)

        denominator = polynomial(params.beta_n)
        # σ_c = (ln albedo_c / P(β_n))², P with the material's own inversion coefficients
        d_colour = np.diag(2.0 * np.log(albedo) / (denominator * denominator * albedo))
        if _live(params.beta_n):
            d_beta_n = -2.0 * params.absorption * _slope(polynomial, params.beta_n) / denominator
    elif mode == "sigma_a":
        d_colour = np.eye(3)
    else:
        d_colour[:, column("eumelanin")], d_colour[:, column("pheomelanin")] = EUMELANIN_SIGMA_A, PHEOMELANIN_SIGMA_A
    return _derivatives(d_colour, d_beta_n, params.beta_m, params.beta_n, params.r_roughness_scale)


def _log_v_slope(beta_m: float) -> float:
    """∂ln v/∂β_m at β_m (0 at the floor)."""
    return _slope(longitudinal_variance, beta_m) / longitudinal_variance(beta_m) if _live(beta_m) else 0.0


def _log_s_slope(beta_n: float) -> float:
    """∂ln s/∂β_n at β_n (0 at the floor)."""
    return _slope(logistic_scale, beta_n) / logistic_scale(beta_n) if _live(beta_n) else 0.0


def _m_norm_log_slope(v):
    """∂ln m_norm/∂ln v of m_norm = 1 / (v (1 − e^(−y))), y = 2/v: −1 + y e^(−y) / (1 − e^(−y)), no overflow at
    small v (NumPy, elementwise)."""
    y = 2.0 / v
    return -1.0 + y * np.exp(-y) / -np.expm1(-y)


def _n_norm_log_slope(s, exp=math.exp, expm1=math.expm1):
    """∂ln n_norm/∂ln s of n_norm = 1 / (s tanh(z/2)), z = π/s: −1 + z / sinh z, formed with e^(−z) (scalar, or
    elementwise with NumPy's exp and expm1)."""
    z = math.pi / s
    return -1.0 + 2.0 * z * exp(-z) / -expm1(-2.0 * z)


def _derivatives(d_colour, d_beta_n, beta_m, beta_n, r_roughness_scale) -> CoefficientDerivatives:
    """CoefficientDerivatives of a material with these roughnesses, from ∂σ_a/∂θ."""
    k = CoefficientDerivatives()
    k.d_sigma_d_colour = wp.mat33(*np.ravel(d_colour))
    k.d_sigma_d_beta_n = wp.vec3(*d_beta_n)
    k.d_log_v_d_beta_m = _log_v_slope(beta_m)
    k.d_log_v_r_d_scale = 1.0 / r_roughness_scale
    k.m_norm_log_slope = wp.vec4(*_m_norm_log_slope(lobe_variances(beta_m, r_roughness_scale)))
    k.d_log_s_d_beta_n = _log_s_slope(beta_n)
    k.n_norm_log_slope = _n_norm_log_slope(logistic_scale(beta_n))
    return k


def strand_derivatives(params: HairParams, looks) -> np.ndarray:
    """Each strand's CoefficientDerivatives (model/variation.py's StrandLooks), as a NumPy structured array of
    `CoefficientDerivatives.numpy_dtype()` (`wp.array(..., dtype=CoefficientDerivatives)` takes it): its own
    roughnesses and ∂σ_a/∂θ, the look's β through the strand's (f_r, or 0 where clamped), the spreads' columns."""
    beta_m, beta_n = looks.beta_m, looks.beta_n
    live_m, live_n = beta_m > BETA_FLOOR, beta_n > BETA_FLOOR
    # ∂ln v/∂β and ∂ln s/∂β at each strand's own β (0 at the floor), by the complex step as `_slope`.
    step = 1e-30
    log_v = np.where(live_m, np.imag(longitudinal_variance(beta_m + 1j * step)) / step, 0.0)
    log_v = log_v / longitudinal_variance(beta_m)
    s = logistic_scale(beta_n)
    log_s = np.where(live_n, np.imag(logistic_scale(beta_n + 1j * step)) / step, 0.0) / s
    table = np.zeros(len(beta_m), dtype=CoefficientDerivatives.numpy_dtype())
    table["d_sigma_d_colour"] = looks.d_sigma_d_colour
    table["d_sigma_d_beta_n"] = looks.d_sigma_d_beta_n
    table["d_log_v_d_beta_m"] = log_v * looks.d_beta_m_d_beta_m
    table["d_log_v_r_d_scale"] = 1.0 / params.r_roughness_scale
    table["m_norm_log_slope"] = _m_norm_log_slope(lobe_variances(beta_m, params.r_roughness_scale).T)
    table["d_log_s_d_beta_n"] = log_s * looks.d_beta_n_d_beta_n
    table["n_norm_log_slope"] = _n_norm_log_slope(s, np.exp, np.expm1)
    table["d_sigma_d_color_spread"] = looks.d_sigma_d_color_spread
    table["d_sigma_d_roughness_spread"] = looks.d_sigma_d_roughness_spread
    table["d_log_v_d_roughness_spread"] = log_v * looks.d_beta_m_d_spread
    table["d_log_s_d_roughness_spread"] = log_s * looks.d_beta_n_d_spread
    return table


@wp.struct
class LobeSetupGrad:
    """The wo- and h-dependent derivatives of one vertex (the counterpart of LobeSetup)."""

    dA_d_sigma: mat43  # ∂A_pc/∂σ_a,c: A_pc depends on its own channel's σ_a only
    dA_d_eta: mat43
    dphi_d_eta: wp.vec3  # ∂Φ_p/∂η, p = R (0), TT, TRT
    tilt: wp.vec4  # ∂θ_o,p/∂α per degree, of the angle whose (sin, |cos|) the lobe uses: past the pole it turns back


@wp.func
def lobe_setup_grad(L: LobeSetup, wo: wp.vec3, h: float):
    """The derivatives of `lobe_setup(c, wo, h)`'s attenuation, azimuthal centres and tilt, given its result L."""
    sin_o = wp.clamp(wo[0], -1.0, 1.0)
    cos_o = cos_from_sin(sin_o)
    h = wp.clamp(h, -1.0, 1.0)
    eta = L.c.eta
    sin_t = sin_o / eta
    cos_t = cos_from_sin(sin_t)
    q2 = eta * eta - sin_o * sin_o
    sin_gamma_t = h * cos_o / wp.sqrt(q2)
    cos_gamma_t = cos_from_sin(sin_gamma_t)
    # sin γ_t = h cos θ_o / sqrt(η² − sin² θ_o), sin θ_t = sin θ_o / η; T = e^(−σ_a ℓ), ℓ = 2 cos γ_t / cos θ_t.
    d_gamma_t = float(0.0)
    if cos_gamma_t > 0.0:  # |sin γ_t| < |h| ≤ 1 for η > 1; only float32 rounding reaches 1
        d_gamma_t = -sin_gamma_t * eta / (q2 * cos_gamma_t)
    d_cos_gamma_t = -sin_gamma_t * d_gamma_t
    inv_cos_t = 1.0 / cos_t
    d_cos_t = sin_t * sin_t * inv_cos_t / eta
    length = 2.0 * cos_gamma_t * inv_cos_t
    d_length = 2.0 * (d_cos_gamma_t - cos_gamma_t * d_cos_t * inv_cos_t) * inv_cos_t
    f = L.A[0, 0]
    df = fresnel_dielectric_d_eta(cos_o * cos_from_sin(h), eta)

    # T from A_TT = (1 − f)² T rather than a second exp; where f = 1 (grazing) every term T enters is 0.
    g = 1.0 - f
    inv_g2 = float(0.0)
    if g > 0.0:
        inv_g2 = 1.0 / (g * g)

    G = LobeSetupGrad()
    for c in range(3):
        sigma = L.c.sigma_a[c]
        T = L.A[1, c] * inv_g2
        d_f, d_t = attenuation_partials(f, T)
        dT_d_sigma = -length * T
        dT_d_eta = -sigma * d_length * T
        for p in range(4):
            G.dA_d_sigma[p, c] = d_t[p] * dT_d_sigma
            G.dA_d_eta[p, c] = d_f[p] * df + d_t[p] * dT_d_eta
    G.dphi_d_eta = wp.vec3(0.0, 2.0 * d_gamma_t, 4.0 * d_gamma_t)

    # The signed cosines of the tilted angles, as lobe_setup forms them before taking |cos|.
    sa = L.c.sin_2k_alpha
    ca = L.c.cos_2k_alpha
    signed_cos = wp.vec3(cos_o * ca[1] - sin_o * sa[1], cos_o * ca[0] + sin_o * sa[0], cos_o * ca[2] + sin_o * sa[2])
    G.tilt = _TILT
    for p in range(3):
        if signed_cos[p] < 0.0:
            G.tilt[p] = -_TILT[p]
    return G


@wp.struct
class LobeEvaluation:
    """One evaluation of the lobes toward wi, with the log-derivatives of each D_p = M_p N_p in its own
    parameters: what `hair_value_jacobian` combines into ∂S/∂θ. Kept apart from the combination so that the
    tracer pays for it only where a derivative is needed: a continuation once Russian roulette has let the path
    go on, a light sample once it contributes."""

    d: wp.vec4  # D_p
    log_v: wp.vec4  # ∂ln M_p/∂ln v_p, less ∂ln m_norm_p/∂ln v_p
    theta_o: wp.vec4  # ∂ln M_p/∂θ_o,p
    log_s: wp.vec3  # ∂ln N_p/∂ln s, less ∂ln n_norm/∂ln s
    x: wp.vec3  # ∂ln N_p/∂x_p, x_p = Δφ − Φ_p wrapped to [−π, π)


@wp.func
def hair_value_pdf_lobes(L: LobeSetup, wi: Incident):
    """(S, pdf, E): `hair_value_pdf_at(L, wi)` (the same operations on the same values, so the same floats) and the
    LobeEvaluation of `hair_value_jacobian`."""
    E = LobeEvaluation()
    sin_i = wi.sin_i
    cos_i = wi.cos_i
    dphi = wi.dphi
    for p in range(4):
        m, log_v, theta_o = longitudinal_scattering_with_slopes(
            sin_i, cos_i, L.sin_o[p], L.cos_o[p], L.c.inv_v[p], L.c.m_norm[p]
        )
        E.log_v[p] = log_v
        E.theta_o[p] = theta_o
        if p < 3:
            x = float(wrap_angle(dphi - L.phi_center[p]))
            n, slope = trimmed_logistic_with_slope(x, L.c.inv_s, L.c.n_norm)
            E.d[p] = m * n
            E.log_s[p] = wp.abs(x) * slope
            E.x[p] = -wp.sign(x) * slope
        else:
            E.d[p] = m * INV_TWO_PI
    d = E.d
    return lobe_sum(L.A, d), wp.dot(L.prob, d), E


@wp.func
def hair_value_jacobian(L: LobeSetup, G: LobeSetupGrad, k: CoefficientDerivatives, E: LobeEvaluation):
    """J[c, j] = ∂S_c/∂θ_j toward the direction E was evaluated at (`hair_value_pdf_lobes`)."""
    d = E.d
    log_v = E.log_v + k.m_norm_log_slope
    n_norm = k.n_norm_log_slope
    log_s = wp.vec4(E.log_s[0] + n_norm, E.log_s[1] + n_norm, E.log_s[2] + n_norm, 0.0)
    # x_p = Δφ − Φ_p: ∂x_p/∂η = −∂Φ_p/∂η.
    d_eta = wp.vec4(-E.x[0] * G.dphi_d_eta[0], -E.x[1] * G.dphi_d_eta[1], -E.x[2] * G.dphi_d_eta[2], 0.0)

    d_sigma = lobe_sum(G.dA_d_sigma, d)  # ∂S_c/∂σ_a,c
    d_log_v = lobe_sum(L.A, wp.cw_mul(d, log_v))  # ∂S_c/∂ln v (every lobe's v scales together)
    d_log_s = lobe_sum(L.A, wp.cw_mul(d, log_s))  # ∂S_c/∂ln s
    d_beta_m = d_log_v * k.d_log_v_d_beta_m
    d_beta_n = d_log_s * k.d_log_s_d_beta_n + wp.cw_mul(d_sigma, k.d_sigma_d_beta_n)
    d_roughness_spread = (
        d_log_v * k.d_log_v_d_roughness_spread
        + d_log_s * k.d_log_s_d_roughness_spread
        + wp.cw_mul(d_sigma, k.d_sigma_d_roughness_spread)
    )
    d_tilt = lobe_sum(L.A, wp.cw_mul(d, wp.cw_mul(G.tilt, E.theta_o)))
    d_index = lobe_sum(L.A, wp.cw_mul(d, d_eta)) + lobe_sum(G.dA_d_eta, d)
    d_scale = (d[0] * log_v[0] * k.d_log_v_r_d_scale) * L.A[0]
    J = value_jacobian_mat()
    for c in range(3):
        for j in range(_COLOUR_COLUMNS):
            J[c, j] = d_sigma[c] * k.d_sigma_d_colour[c, j]
        J[c, _BETA_M] = d_beta_m[c]
        J[c, _BETA_N] = d_beta_n[c]
        J[c, _ALPHA] = d_tilt[c]
        J[c, _ETA] = d_index[c]
        J[c, _R_ROUGHNESS_SCALE] = d_scale[c]
        J[c, _COLOR_SPREAD] = d_sigma[c] * k.d_sigma_d_color_spread[c]
        J[c, _ROUGHNESS_SPREAD] = d_roughness_spread[c]
        J[c, _TIP_ABSORPTION] = d_sigma[c] * k.d_sigma_d_tip_absorption[c]
        J[c, _TIP_LENGTH] = d_sigma[c] * k.d_sigma_d_tip_length[c]
    return J
