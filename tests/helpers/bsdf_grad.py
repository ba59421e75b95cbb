"""Derivatives of the hair BSDF value S (RGB) and of its pdf with respect to the artist controls.

In kernels the controls travel as a `HairControls`: the eight floats `theta`, laid out as the table of
`warp_hair.controls` says (colour in 0-2, then β_m, β_n, α in degrees, η, r_roughness_scale), and the colour
input's kind (COLOUR_ALBEDO, COLOUR_SIGMA_A, COLOUR_MELANIN).

Usage inside a kernel (`controls = hair_controls(params)` on the host):
    J = hair_value_pdf_jacobian(controls, wo, wi, h)   # 4×8: rows ∂S_r, ∂S_g, ∂S_b, ∂pdf; columns θ_k
    g = hair_value_pdf_vjp(controls, wo, wi, h, seed)  # Σ_r seed_r · J[r]: one row's cost (a seed of
                                                       # adjoint radiance weights needs no full Jacobian)
A path tracer accumulates ∂ log S_c/∂θ_k as J[c, k] / S_c, with S_c from `hair_value_pdf` as before. The
renderer's gradient tracer uses the closed form of `warp_hair.model.jacobian` instead (one evaluation of the
lobes for S and ∂S, no reverse pass); this module, Warp's reverse mode through the model as written, is its
check. It is test code (tests/test_bsdf_grad.py, test_bsdf_jacobian.py, test_controls.py) and not shipped.

Call these two from a kernel, or from a `wp.func` that itself calls `wp.grad`. Warp 1.19 emits every function
that calls `wp.grad` after all others (they call adjoints, which are emitted in between), so a plain
`wp.func` that calls one of them is compiled before its callee is declared and the module fails to build
("use of undeclared identifier 'hair_value_pdf_vjp_0'").
Nor may a kernel in the same module call `coefficients_from_controls` (or the mappings under it) without
wp.grad: Warp 1.19 builds that kernel first, its helpers keep stub adjoints in the module, and wp.grad then
returns 0 for β_m, β_n and the colour (give such a kernel a module of its own: `@wp.kernel(module="unique")`).

The derivatives are Warp's own reverse mode, run inside the forward kernel by `wp.grad`: the scalar
seed·(S, pdf) is written as one `wp.func` of the controls (`value_pdf_dot`), which maps them to the model
coefficients in Warp (`coefficients_from_controls`, the same mappings as `params.py`) and then calls the
renderer's own `lobe_setup` and `hair_value_pdf`, unchanged. wp.grad differentiates all of it as written:
the float64 azimuthal centres, clamp/max/abs/floor, the structs passed along, the two-value return of
`hair_value_pdf`, the loops that assign vector components. One reverse pass per seed, so the full
Jacobian costs four. Everything is float32, like the value itself.

The chain through the albedo inversion is included: with albedo as colour input, σ_a depends on β_n, so
∂/∂β_n carries both the azimuthal-roughness path and the absorption path.

Where the model is not differentiable the derivative is one-sided or zero, never NaN (h = ±1 and grazing
directions included):
  - β_m, β_n at or below the roughness floor (`params.BETA_FLOOR`, 0.01) are rendered as the floor, so their
    derivative there is 0 (the floor is a clamp; gradient-based fits must keep β above it);
  - at the kinks of the model itself the derivative is that of one side: the azimuth wrap at
    Δφ − Φ_p = ±π (moved by η), the |cos| of a tilted θ_o passing the pole (moved by α).

NumPy batch API (shapes as `bsdf.eval`):
    dS = eval_grad(params, wo, wi, h)    # {control: (N, 3) for scalars, (N, 3, 3) for RGB controls}
    dp = pdf_grad(params, wo, wi, h)     # {control: (N,) for scalars, (N, 3) for RGB controls}
For an RGB control, dS[name][i, c, k] = ∂S_c/∂control_k (middle axis: channel of S, last: component).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from warp_hair.controls import COLOUR_INPUTS, THETA_SIZE, column, named_theta, theta_vector
from warp_hair.controls import SCALAR_CONTROLS as SCALAR_NAMES
from warp_hair.model.bsdf import check_directions, check_offsets, check_params, launch_batch
from warp_hair.model.hair_bsdf import HairCoefficients, hair_value_pdf, lobe_setup
from warp_hair.model.jacobian import controls_vec
from warp_hair.model.params import (
    ALBEDO_INVERSION_DEGREE,
    BETA_FLOOR,
    EUMELANIN_SIGMA_A,
    PHEOMELANIN_SIGMA_A,
    HairParams,
)
from warp_hair.numerics import PI

# wp.grad runs forward only: the kernels here need no backward pass of their own.
wp.set_module_options({"enable_backward": False})

CONTROL_COUNT = THETA_SIZE
inversion_vec = wp.types.vector(length=ALBEDO_INVERSION_DEGREE + 1, dtype=wp.float32)
jacobian_mat = wp.types.matrix(shape=(4, CONTROL_COUNT), dtype=wp.float32)

# The kernels' code for each colour input.
COLOUR_MODES = {colour_input: k for k, colour_input in enumerate(COLOUR_INPUTS)}
COLOUR_ALBEDO = wp.constant(COLOUR_MODES["albedo"])
COLOUR_SIGMA_A = wp.constant(COLOUR_MODES["sigma_a"])
COLOUR_MELANIN = wp.constant(COLOUR_MODES["melanin"])

# Column of each scalar control in theta.
SCALAR_CONTROLS = {name: column(name) for name in SCALAR_NAMES}
# The variation's controls (model/variation.py) act per strand, not in one material's BSDF: their columns are 0 here.
BETA_M, BETA_N, ALPHA, ETA, R_ROUGHNESS_SCALE = (
    SCALAR_CONTROLS[name] for name in ("beta_m", "beta_n", "alpha", "eta", "r_roughness_scale")
)

# Rows of the Jacobian: S_r, S_g, S_b, pdf.
VALUE_ROWS = (0, 1, 2)
PDF_ROW = 3

_EUMELANIN = wp.constant(wp.vec3(*EUMELANIN_SIGMA_A))
_PHEOMELANIN = wp.constant(wp.vec3(*PHEOMELANIN_SIGMA_A))
_BETA_FLOOR = wp.constant(BETA_FLOOR)
_SQRT_PI_OVER_8 = wp.constant(math.sqrt(math.pi / 8.0))
_RADIANS = wp.constant(math.pi / 180.0)


@wp.struct
class HairControls:
    """The artist controls of one material as kernels differentiate them (ordering in the module docstring),
    and the coefficients p_0 ... p_5 of its albedo inversion (HairParams.albedo_inversion; not differentiated)."""

    theta: controls_vec
    colour_mode: int
    albedo_inversion: inversion_vec


def hair_controls(params: HairParams) -> HairControls:
    """The HairControls of a HairParams: its colour input as given, then the five scalar controls."""
    k = HairControls()
    mode = params.colour_input
    k.theta = controls_vec(*theta_vector(mode, params.to_dict()))
    k.colour_mode = COLOUR_MODES[mode]
    k.albedo_inversion = inversion_vec(*params.albedo_inversion)
    return k


# The control → coefficient mappings of params.py, in Warp so that reverse mode can run through them.
# tests/test_bsdf_grad.py checks that they build the same HairCoefficients as `hair_coefficients`.


@wp.func
def effective_beta(beta: float):
    """max(β, floor): at and below the floor the derivative with respect to β is 0."""
    return wp.max(beta, _BETA_FLOOR)


@wp.func
def longitudinal_variance(beta_m: float):
    b = effective_beta(beta_m)
    r = b * (0.726 + 0.812 * b) + 3.7 * wp.pow(b, 20.0)
    return r * r


@wp.func
def logistic_scale(beta_n: float):
    b = effective_beta(beta_n)
    return _SQRT_PI_OVER_8 * (b * (0.265 + 1.194 * b) + 5.372 * wp.pow(b, 22.0))


@wp.func
def albedo_denominator(beta_n: float, p: inversion_vec):
    b = effective_beta(beta_n)
    return p[0] + b * (p[1] + b * (p[2] + b * (p[3] + b * (p[4] + b * p[5]))))


@wp.func
def sigma_a_from_controls(theta: controls_vec, colour_mode: int, inversion: inversion_vec):
    colour = wp.vec3(theta[0], theta[1], theta[2])
    if colour_mode == COLOUR_ALBEDO:
        d = albedo_denominator(theta[BETA_N], inversion)
        r = wp.vec3(wp.log(colour[0]), wp.log(colour[1]), wp.log(colour[2])) / d
        return wp.cw_mul(r, r)
    if colour_mode == COLOUR_MELANIN:
        return colour[0] * _EUMELANIN + colour[1] * _PHEOMELANIN
    return colour


@wp.func
def longitudinal_norm(v: float):
    """1 / (v (1 − e^(−2/v))), in float64 like `lobes.longitudinal_norm` on the host.

    Not a short series for 1 − e^(−y): one of 4 terms is exact enough for the value, but its derivative is
    off by up to (2/v)³/24 relative, and d log norm/dv ≈ −1/v + 1/v − 1/v² + … cancels to O(1/v²) for rough
    lobes: the series would put errors of up to 2 % in ∂S/∂β_m near β_m ≈ 0.9. In float64, 1 − e^(−y) keeps 1e-12 of
    its digits even at y = 2/v ~ 1e-4, and no series is needed.
    """
    vd = wp.float64(v)
    return float(wp.float64(1.0) / (vd * (wp.float64(1.0) - wp.exp(wp.float64(-2.0) / vd))))


@wp.func
def coefficients_from_controls(theta: controls_vec, colour_mode: int, inversion: inversion_vec):
    """The HairCoefficients of the controls, as `hair_coefficients` builds them, but differentiable.

    `n_tail` and `cone` (used only by sampling) are left at 0: nothing differentiated here samples.
    """
    c = HairCoefficients()
    c.sigma_a = sigma_a_from_controls(theta, colour_mode, inversion)
    c.eta = theta[ETA]
    v = longitudinal_variance(theta[BETA_M])
    lobe_v = wp.vec4(v * theta[R_ROUGHNESS_SCALE], 0.25 * v, 4.0 * v, 4.0 * v)
    c.inv_v = wp.vec4(1.0 / lobe_v[0], 1.0 / lobe_v[1], 1.0 / lobe_v[2], 1.0 / lobe_v[3])
    c.m_norm = wp.vec4(
        longitudinal_norm(lobe_v[0]),
        longitudinal_norm(lobe_v[1]),
        longitudinal_norm(lobe_v[2]),
        longitudinal_norm(lobe_v[3]),
    )
    s = logistic_scale(theta[BETA_N])
    c.s = s
    c.inv_s = 1.0 / s
    c.n_norm = 1.0 / (s * wp.tanh(PI / (2.0 * s)))
    a = theta[ALPHA] * _RADIANS
    c.sin_2k_alpha = wp.vec3(wp.sin(a), wp.sin(2.0 * a), wp.sin(4.0 * a))
    c.cos_2k_alpha = wp.vec3(wp.cos(a), wp.cos(2.0 * a), wp.cos(4.0 * a))
    return c


@wp.func
def value_pdf_dot(
    theta: controls_vec, colour_mode: int, inversion: inversion_vec, wo: wp.vec3, wi: wp.vec3, h: float, seed: wp.vec4
):
    """seed · (S_r, S_g, S_b, pdf): the scalar whose gradient `wp.grad` takes.

    wp.grad seeds the adjoint of every output with 1, so of a function returning (S, pdf) it would give the
    gradient of S_r + S_g + S_b + pdf; the seed picks the combination instead.
    """
    value, density = hair_value_pdf(lobe_setup(coefficients_from_controls(theta, colour_mode, inversion), wo, h), wi)
    return seed[0] * value[0] + seed[1] * value[1] + seed[2] * value[2] + seed[3] * density


@wp.func
def hair_value_pdf_vjp(controls: HairControls, wo: wp.vec3, wi: wp.vec3, h: float, seed: wp.vec4):
    """Σ_r seed_r ∂(S_r, S_g, S_b, pdf)_r / ∂θ: one reverse pass."""
    d_theta, _d_mode, _d_inversion, _d_wo, _d_wi, _d_h, _d_seed = wp.grad(value_pdf_dot)(
        controls.theta, controls.colour_mode, controls.albedo_inversion, wo, wi, h, seed
    )
    return d_theta


@wp.func
def hair_value_pdf_jacobian(controls: HairControls, wo: wp.vec3, wi: wp.vec3, h: float):
    """J[r, k] = ∂(S_r, S_g, S_b, pdf)_r / ∂θ_k, row by row (four reverse passes).

    Calls wp.grad itself rather than `hair_value_pdf_vjp`: see the module docstring on where these
    functions may be called from.
    """
    J = jacobian_mat()
    for r in range(4):
        seed = wp.vec4(0.0)
        seed[r] = 1.0
        d_theta, _d_mode, _d_inversion, _d_wo, _d_wi, _d_h, _d_seed = wp.grad(value_pdf_dot)(
            controls.theta, controls.colour_mode, controls.albedo_inversion, wo, wi, h, seed
        )
        J[r] = d_theta
    return J


@wp.kernel
def _vjp_kernel(
    controls: HairControls,
    seeds: wp.array(dtype=wp.vec4),
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array2d(dtype=controls_vec),
    first: int,
):
    i = wp.tid() + first
    for r in range(seeds.shape[0]):
        out[i, r] = hair_value_pdf_vjp(controls, wo[i], wi[i], h[i], seeds[r])


def _gradients(params, wo, wi, h, rows, threads, device) -> np.ndarray:
    """(N, len(rows), 8): the chosen rows of the Jacobian per item, after the checks of `bsdf.eval`."""
    check_params(params)  # the type check; the coefficients are rebuilt in the kernel from the controls
    seeds = wp.array(np.eye(4, dtype=np.float32)[list(rows)], dtype=wp.vec4, device=device)
    items = {"wo": check_directions("wo", wo), "wi": check_directions("wi", wi), "h": check_offsets(h)}
    leading = [hair_controls(params), seeds]
    return launch_batch(_vjp_kernel, leading, items, [((len(rows),), controls_vec)], threads, device)[0]


def _by_control(params: HairParams, g: np.ndarray) -> dict:
    """Name the columns of g (..., 8): the colour input's own name(s), then the scalar controls."""
    return named_theta(params.colour_input, g)


def eval_grad(params: HairParams, wo, wi, h, threads: int | None = None, device: str = "cpu") -> dict:
    """∂S/∂control per item: (N, 3) for scalar controls; (N, 3, 3) for albedo or σ_a, [item, channel of S,
    component of the control]. Melanin inputs give "eumelanin" and "pheomelanin", each (N, 3)."""
    return _by_control(params, _gradients(params, wo, wi, h, VALUE_ROWS, threads, device))


def pdf_grad(params: HairParams, wo, wi, h, threads: int | None = None, device: str = "cpu") -> dict:
    """∂pdf/∂control per item: (N,) for scalar controls, (N, 3) for albedo or σ_a. The pdf depends on the
    colour through the lobe probabilities (channel means of A_p)."""
    return _by_control(params, _gradients(params, wo, wi, h, (PDF_ROW,), threads, device)[:, 0])
