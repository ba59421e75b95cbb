"""Numeric helpers shared by the model, the geometry and the renderer, each defined once (pbrt's util/math.h).

Constants, then the float32 functions that keep the model and the integrator accurate at the extremes: the
scaled Bessel function of M (with M's exponential), log1p for narrow cones, cos from sin near
grazing; the power heuristic, local frames and pairs of random numbers for the integrator. Warp constants are
folded into the kernels that use them; the float32 ones round the exact value once.
"""

import math

import warp as wp

PI = wp.constant(math.pi)
TWO_PI = wp.constant(2.0 * math.pi)
INV_PI = wp.constant(1.0 / math.pi)
INV_TWO_PI = wp.constant(1.0 / (2.0 * math.pi))
INV_FOUR_PI = wp.constant(1.0 / (4.0 * math.pi))
# In float64, for the steps the model takes in double precision.
PI64 = wp.constant(wp.float64(math.pi))
TWO_PI64 = wp.constant(wp.float64(2.0 * math.pi))

# The smallest normal float32. A sampled direction whose density is below it carries no weight: the ratio S/pdf
# of two subnormals is off by up to a percent, and such a direction (the far tail of a very narrow lobe) is drawn
# with a probability near 1e-38.
FLOAT32_MIN_NORMAL = wp.constant(1.17549435e-38)

# The distance of "no hit" along a unit ray: beyond every scene (positions are at most 1e15 in magnitude).
NO_HIT = wp.constant(1.0e30)


# Special functions (the model's lobes).


@wp.func
def _i0_series(t: float):
    """I0(x) for x < 3.75 as a polynomial in t = (x / 3.75)² (Abramowitz & Stegun 9.8.1, relative error < 2e-7)."""
    return 1.0 + t * (3.5156229 + t * (3.0899424 + t * (1.2067492 + t * (0.2659732 + t * (0.0360768 + t * 0.0045813)))))


@wp.func
def _i0e_asymptotic(y: float):
    """√x I0(x) e^(−x) for x ≥ 3.75 as a polynomial in y = 3.75 / x (Abramowitz & Stegun 9.8.2, < 2e-7)."""
    return 0.39894228 + y * (
        0.01328592
        + y
        * (
            0.00225319
            + y
            * (
                -0.00157565
                + y * (0.00916281 + y * (-0.02057706 + y * (0.02635537 + y * (-0.01647633 + y * 0.00392377))))
            )
        )
    )


@wp.func
def bessel_i0e_times_exp(x: float, y: float):
    """I0(x)·e^(−x)·e^y for x ≥ 0 and y ≤ 0, with one exponential: below 3.75 the series gives I0 itself and the
    e^(−x) joins the e^y, above it the asymptotic form gives I0·e^(−x) without one (relative error < 5e-7).

    The scaled form never overflows, and its e^(−x) cancels the e^(+a) of M analytically
    (`lobes.longitudinal_scattering`, where y ≤ 0 is M's other exponent); y − x sums two non-positive terms, so
    it does not cancel.
    """
    if x < 3.75:
        t = x / 3.75
        return _i0_series(t * t) * wp.exp(y - x)
    return _i0e_asymptotic(3.75 / x) / wp.sqrt(x) * wp.exp(y)


@wp.func
def bessel_i0e_times_exp_with_log_slope(x: float, y: float):
    """(bessel_i0e_times_exp(x, y), d ln(I0(x) e^(−x))/dx) from one evaluation of the same polynomials: the value
    by the same operations as `bessel_i0e_times_exp` (so the same float32 result), the slope the exact one of that
    value's Bessel factor (within 5e-6 relative of I1(x)/I0(x) − 1 over [0, 1e6]).

    Both slopes are sums of terms of one sign: for large x it is −(1/2 + y q'(y)/q(y))/x, with no 1 − I1/I0
    cancellation.
    """
    if x < 3.75:
        t = x / 3.75
        t = t * t
        i0 = _i0_series(t)
        d_i0 = 3.5156229 + t * (
            2.0 * 3.0899424
            + t * (3.0 * 1.2067492 + t * (4.0 * 0.2659732 + t * (5.0 * 0.0360768 + t * (6.0 * 0.0045813))))
        )
        return i0 * wp.exp(y - x), d_i0 * (x * (2.0 / (3.75 * 3.75))) / i0 - 1.0
    z = 3.75 / x
    poly = _i0e_asymptotic(z)
    d_poly = 0.01328592 + z * (
        2.0 * 0.00225319
        + z
        * (
            3.0 * -0.00157565
            + z
            * (
                4.0 * 0.00916281
                + z * (5.0 * -0.02057706 + z * (6.0 * 0.02635537 + z * (7.0 * -0.01647633 + z * (8.0 * 0.00392377))))
            )
        )
    )
    return poly / wp.sqrt(x) * wp.exp(y), -(0.5 + z * d_poly / poly) * (z * (1.0 / 3.75))  # 1/x = z/3.75


@wp.func
def log1p(x: float):
    """ln(1 + x) to full relative precision for small x (Goldberg's trick: the rounding of 1 + x cancels)."""
    y = 1.0 + x
    if y == 1.0:
        return x
    return wp.log(y) * x / (y - 1.0)


# Trigonometry.


@wp.func
def cos_from_sin(sin_x: float):
    """cos x ≥ 0 from sin x as sqrt((1 − sin)(1 + sin)): no cancellation near grazing, unlike 1 − sin²."""
    return wp.sqrt(wp.max(0.0, (1.0 - sin_x) * (1.0 + sin_x)))


# Monte Carlo.


@wp.func
def power_heuristic(pdf_a: float, pdf_b: float):
    """The weight of a sample drawn with density pdf_a against a second strategy's pdf_b (Veach 1997, β = 2)."""
    a = pdf_a * pdf_a
    return a / (a + pdf_b * pdf_b)


@wp.func
def rand2(rng: wp.uint32):
    """(two uniforms in [0, 1), rng): one pair from a stream, in order."""
    a = wp.randf(rng)
    b = wp.randf(rng)
    return wp.vec2(a, b), rng


# Frames.


@wp.func
def to_local(w: wp.vec3, x: wp.vec3, y: wp.vec3, z: wp.vec3):
    """World direction w in the orthonormal frame (x, y, z)."""
    return wp.vec3(wp.dot(w, x), wp.dot(w, y), wp.dot(w, z))


@wp.func
def to_world(w: wp.vec3, x: wp.vec3, y: wp.vec3, z: wp.vec3):
    """Local direction w of the orthonormal frame (x, y, z) in world coordinates."""
    return w[0] * x + w[1] * y + w[2] * z


@wp.func
def perpendicular(n: wp.vec3):
    """Any unit vector ⊥ n (Duff et al. 2017)."""
    sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
