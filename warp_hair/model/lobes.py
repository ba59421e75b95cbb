"""The three factors of every lobe of the Chiang et al. model, as allocation-free Warp functions.

S = Σ_p M_p(θ_i, θ_o) A_p(θ_o, h) N_p(Δφ, h): M is d'Eon et al.'s longitudinal scattering, A the
attenuation along the internal path, N the azimuthal distribution (a trimmed logistic). All in float32,
arranged so that no step overflows or cancels catastrophically at the extremes (tiny or huge variance,
grazing angles, h = ±1, σ_a = 0).
"""

import numpy as np
import warp as wp

from ..numerics import (
    PI,
    PI64,
    TWO_PI,
    TWO_PI64,
    bessel_i0e_times_exp,
    bessel_i0e_times_exp_with_log_slope,
    log1p,
)

mat43 = wp.types.matrix(shape=(4, 3), dtype=wp.float32)


def longitudinal_norm(v):
    """1 / (v (1 − e^(−2/v))), M's normalisation, in float64 on the host (NumPy)."""
    return 1.0 / (v * -np.expm1(-2.0 / v))


def logistic_norm(s):
    """1 / (s tanh(π / 2s)): the trimmed logistic's normalisation, CDF(π) − CDF(−π) = tanh(π / 2s)."""
    return 1.0 / (s * np.tanh(np.pi / (2.0 * s)))


def logistic_tail(s):
    """CDF(−π) = 1 / (1 + e^(π/s)) of the logistic of scale s, without overflow for small s."""
    return np.exp(-np.logaddexp(0.0, np.pi / s))


@wp.func
def cos_sum_minus_one(sin_a: float, cos_a: float, sin_b: float, cos_b: float):
    """cos(a + b) − 1, accurate near 0 where the direct difference would lose all digits."""
    cos_sum = cos_a * cos_b - sin_a * sin_b
    if cos_sum < 0.0:
        return cos_sum - 1.0
    sin_sum = sin_a * cos_b + cos_a * sin_b
    return -sin_sum * sin_sum / (1.0 + cos_sum)


@wp.func
def longitudinal_scattering(sin_i: float, cos_i: float, sin_o: float, cos_o: float, inv_v: float, norm: float):
    """M(θ_i, θ_o; v) = I0(cos θ_i cos θ_o / v) e^(−sin θ_i sin θ_o / v) / (2 v sinh(1/v)) (d'Eon 2011).

    With a = cos θ_i cos θ_o / v and 2 sinh(1/v) = e^(1/v)(1 − e^(−2/v)):
        M = I0e(a) · exp((cos(θ_i + θ_o) − 1) / v) / (v (1 − e^(−2/v))),
    because a − sin θ_i sin θ_o / v − 1/v = (cos(θ_i + θ_o) − 1)/v. Every factor is ≤ 1 or a plain
    division, so tiny v (log-space territory in pbrt) and huge v are both exact to float32 precision; the two
    exponentials are taken as one (`bessel_i0e_times_exp`).
    `inv_v` = 1/v and `norm` = 1/(v (1 − e^(−2/v))) depend on the material only: `longitudinal_norm`.
    """
    e = cos_sum_minus_one(sin_i, cos_i, sin_o, cos_o)
    return bessel_i0e_times_exp(cos_i * cos_o * inv_v, e * inv_v) * norm


# Below this variance e^(2/v) overflows float32: the far-hemisphere form of the cone sample is not used there.
_FAR_FORM_MIN_V = 0.025


def cone_constants(v):
    """Rows (v, 1 − e^(−2/v), e^(−2/v), e^(2/v) − 1) per lobe variance v, in float64 on the host: what
    `sample_longitudinal_cone` needs of the material, formed once rather than by three float32 exponentials a sample.
    The last is 0 where it would overflow float32 (v ≤ 0.025 as the kernel reads v, in float32), which tells the
    sampler not to use it."""
    v = np.asarray(v, dtype=np.float64)
    usable = v.astype(np.float32) > np.float32(_FAR_FORM_MIN_V)
    growth = np.where(usable, np.expm1(2.0 / np.maximum(v, _FAR_FORM_MIN_V)), 0.0)
    return np.stack([v, -np.expm1(-2.0 / v), np.exp(-2.0 / v), growth], axis=-1)


@wp.func
def sample_longitudinal_cone(u: float, cone: wp.vec4):
    """(1 − cos θ, 1 + cos θ) for a sample of the cone angle θ about the mirror direction of M(·, θ_o; v), with
    `cone` the lobe's row of `cone_constants(v)`.

    d'Eon's inversion is 1 − cos θ = −v ln(u + (1 − u) e^(−2/v)). Each factor is formed where it is
    small: ln(1 − x) through log1p when u is near 1 (narrow cones), and 1 + cos θ = v ln(1 + u(e^(2/v) − 1))
    when the sample lands in the far hemisphere (very rough lobes), so sin θ = sqrt((1 − cos)(1 + cos))
    keeps its digits at both poles. The floor −2/v catches e^(−2/v) underflowing for narrow lobes.
    """
    v = cone[0]
    x = (1.0 - u) * cone[1]
    log_arg = float(0.0)
    if x < 0.5:
        log_arg = log1p(-x)
    else:
        log_arg = wp.log(u + (1.0 - u) * cone[2])
    a = float(2.0)
    if log_arg > -2.0 / v:
        a = wp.min(-v * log_arg, 2.0)
    b = 2.0 - a
    if a > 1.0 and cone[3] > 0.0:  # 0 where e^(2/v) would overflow float32 (`cone_constants`)
        b = v * log1p(u * cone[3])
    return a, b


@wp.func
def sample_longitudinal_sin(u_cone: float, u_rot: float, sin_o: float, cos_o: float, cone: wp.vec4):
    """(sin θ_i, cos θ_i) of a sample of M(·, θ_o; v): a cone of angle θ about the mirror direction −θ_o,
    rotated by 2π u_rot. cos θ_i is built from the orthogonal components, not from 1 − sin² θ_i.
    """
    a, b = sample_longitudinal_cone(u_cone, cone)
    cos_t = 1.0 - a
    if a > 1.0:
        cos_t = b - 1.0
    sin_t = wp.sqrt(a * b)
    c_rot = wp.cos(TWO_PI * u_rot)
    s_rot = wp.sin(TWO_PI * u_rot)
    sin_i = -cos_t * sin_o + sin_t * c_rot * cos_o
    along = cos_t * cos_o + sin_t * c_rot * sin_o
    across = sin_t * s_rot
    return sin_i, wp.sqrt(along * along + across * across)


@wp.func
def fresnel_dielectric(cos_i: float, eta: float):
    """Unpolarized Fresnel reflectance entering a dielectric of index eta > 1 (no total internal reflection)."""
    if cos_i <= 0.0:
        # Grazing: 1 for every eta > 1, and the formulas' 0/0 when eta rounds to 1 in float32.
        return 1.0
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = wp.sqrt(wp.max(0.0, 1.0 - sin2_t))
    r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (r_parl * r_parl + r_perp * r_perp)


@wp.func
def attenuation(f: float, T: wp.vec3):
    """A_p for R, TT, TRT and the residual lobe (rows); the residual carries the whole series p ≥ 3.

    A_0 = f, A_1 = (1−f)² T, A_2 = A_1 f T, A_3 = A_2 f T / (1 − f T) = Σ_{p≥3} (1−f)² f^(p−1) T^p.
    1 − fT is formed as (1 − f) + f(1 − T) to keep digits when both f and T approach 1; when it is 0
    (f = 1 and T = 1, grazing with σ_a = 0) A_2 is 0 as well and so is the sum.
    """
    one = wp.vec3(1.0, 1.0, 1.0)
    a0 = f * one
    a1 = (1.0 - f) * (1.0 - f) * T
    a2 = f * wp.cw_mul(a1, T)
    a3 = wp.vec3(0.0, 0.0, 0.0)
    for c in range(3):
        denom = (1.0 - f) + f * (1.0 - T[c])
        if denom > 0.0:
            a3[c] = a2[c] * f * T[c] / denom
    return wp.matrix_from_rows(a0, a1, a2, a3)


@wp.func
def lobe_sum(A: mat43, w: wp.vec4):
    """Σ_p w_p A_p (the rows of A): one channel-vector per lobe weighted per lobe."""
    return w[0] * A[0] + w[1] * A[1] + w[2] * A[2] + w[3] * A[3]


@wp.func
def wrap_angle(x: wp.float64):
    """x wrapped to [−π, π), in float64 (see LobeSetup.phi_center)."""
    return x - TWO_PI64 * wp.floor((x + PI64) / TWO_PI64)


@wp.func
def trimmed_logistic(x: float, inv_s: float, norm: float):
    """The logistic density of scale s = 1/inv_s restricted to [−π, π] and renormalized there
    (`norm` = `logistic_norm(s)`)."""
    e = wp.exp(-wp.abs(x) * inv_s)
    return e * norm / ((1.0 + e) * (1.0 + e))


@wp.func
def sample_trimmed_logistic(u: float, s: float, tail: float):
    """Inverse CDF of the trimmed logistic on [−π, π].

    With c = CDF(−π) (`tail` = `logistic_tail(s)`) and k = CDF(π) − CDF(−π) = 1 − 2c, the sample is
    s·ln(y / (1 − y)) for y = c + u k; 1 − y is formed as c + (1 − u) k so neither tail cancels.
    """
    k = 1.0 - 2.0 * tail
    x = s * wp.log((tail + u * k) / (tail + (1.0 - u) * k))
    return wp.clamp(x, -PI, PI)


@wp.func
def fresnel_dielectric_d_eta(cos_i: float, eta: float):
    """∂/∂η of `fresnel_dielectric(cos_i, eta)` (η > 1, so cos θ_t > 0)."""
    if cos_i <= 0.0:
        return 0.0  # the reflectance is 1 at grazing for every η
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = wp.sqrt(wp.max(0.0, 1.0 - sin2_t))
    d_cos_t = sin2_t / (eta * cos_t)
    inv_parl = 1.0 / (eta * cos_i + cos_t)
    inv_perp = 1.0 / (cos_i + eta * cos_t)
    r_parl = (eta * cos_i - cos_t) * inv_parl
    r_perp = (cos_i - eta * cos_t) * inv_perp
    d_r_parl = 2.0 * cos_i * (cos_t - eta * d_cos_t) * inv_parl * inv_parl
    d_r_perp = -2.0 * cos_i * (cos_t + eta * d_cos_t) * inv_perp * inv_perp
    return r_parl * d_r_parl + r_perp * d_r_perp


@wp.func
def attenuation_partials(f: float, T: float):
    """(∂A_p/∂f, ∂A_p/∂T) of `attenuation` for one channel, p = R, TT, TRT, residual.

    With A_3 = f²(1 − f)² T³ / (1 − fT): ∂A_3/∂f = (∂_f[f²(1 − f)² T³] + A_3 T) / (1 − fT) and
    ∂A_3/∂T = (3 f²(1 − f)² T² + A_3 f) / (1 − fT); 0 where the denominator is, as A_3 is.
    """
    g = 1.0 - f
    a2 = f * g * g * T * T
    d_f = wp.vec4(1.0, -2.0 * g * T, g * (1.0 - 3.0 * f) * T * T, 0.0)
    d_t = wp.vec4(0.0, g * g, 2.0 * f * g * g * T, 0.0)
    denom = g + f * (1.0 - T)
    if denom > 0.0:
        inv_denom = 1.0 / denom
        a3 = a2 * f * T * inv_denom
        d_f[3] = (2.0 * f * g * (1.0 - 2.0 * f) * T * T * T + a3 * T) * inv_denom
        d_t[3] = (3.0 * a2 * f + a3 * f) * inv_denom
    return d_f, d_t


@wp.func
def longitudinal_scattering_with_slopes(
    sin_i: float, cos_i: float, sin_o: float, cos_o: float, inv_v: float, norm: float
):
    """(M, ∂ln M/∂ln v − ∂ln norm/∂ln v, ∂ln M/∂θ_o): M by the same operations as `longitudinal_scattering`
    (the same float32 value), and the derivatives of its log that ∂S/∂θ needs.

    With a = cos θ_i cos θ_o / v, ln M = ln I0e(a) + (cos(θ_i + θ_o) − 1)/v + ln norm(v), so
        ∂ln M/∂ln v = −a ∂ln I0e/∂a − (cos(θ_i + θ_o) − 1)/v + ∂ln norm/∂ln v,
        ∂ln M/∂θ_o  = −(sin(θ_i + θ_o) + ∂ln I0e/∂a cos θ_i sin θ_o)/v;
    the normalisation's term depends on the material only, and is left to the caller.
    """
    e = cos_sum_minus_one(sin_i, cos_i, sin_o, cos_o)
    a = cos_i * cos_o * inv_v
    i0e_exp, slope = bessel_i0e_times_exp_with_log_slope(a, e * inv_v)
    m = i0e_exp * norm
    return m, -a * slope - e * inv_v, -(sin_i * cos_o + cos_i * sin_o + slope * cos_i * sin_o) * inv_v


@wp.func
def trimmed_logistic_with_slope(x: float, inv_s: float, norm: float):
    """(`trimmed_logistic(x, inv_s, norm)` by the same operations, tanh(|x|/2s)/s): the second gives
    ∂ln N/∂x = −sign(x) tanh(|x|/2s)/s and, with |x|, ∂ln N/∂ln s = |x| tanh(|x|/2s)/s + ∂ln norm/∂ln s."""
    e = wp.exp(-wp.abs(x) * inv_s)
    return e * norm / ((1.0 + e) * (1.0 + e)), (1.0 - e) / (1.0 + e) * inv_s
