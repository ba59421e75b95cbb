"""The closed-form ∂S/∂θ of warp_hair.model.jacobian (the gradient tracer's) against Warp's reverse mode
(bsdf_grad, wp.grad through the same model) and against five-point finite differences of the float64 reference.

Both Warp derivatives are float32, and each is within test_bsdf_grad's allowance of the float64 reference
(RTOL of the terms summed, ATOL·|S|·ν_k for near-stationary entries, ν_k the control's natural log-scale):
the comparison with the reference here is that same test. Against each other:

- interior configurations (test_bsdf_grad's: β ≥ 0.02, |h| < 0.999, R-scale in [0.1, 10]):
  |J − J_wp.grad| ≤ 1e-4 |J_wp.grad| + 1e-5 |S| ν_k;
- edges (h = ±1, grazing wo or wi within 1e-4 of the fiber axis, α = ±10°, β at 1.01× and 1.2× the floor and
  at 0.99 and 1, η in [1.2, 2]): 1e-3 |J_wp.grad| + 5e-5 |S| ν_k.

Measured with five times the materials the tests use (`python tests/test_bsdf_jacobian.py` prints the test's own
sets), the worst entry uses 0.29 of the interior allowance and 0.45 of the edge one, and where J_wp.grad is not
near-stationary (|J_wp.grad| ≥ 0.1 |S| ν_k) the relative difference is at most 4e-5 inside and 3.6e-4 at the
edges. The edges need the looser allowance in the β_m and R-scale columns at β_m ≈ 0.0101 with an R-scale
below 1, where the R lobe's variance is ~1e-5: there ∂ln M/∂ln v = −a ∂ln I0e/∂a − (cos(θ_i + θ_o) − 1)/v
passes through zero about one standard deviation from the peak, and the float32 rounding of the tilted angles
(~6e-8 rad; the two sides form sin α, cos α differently, in float64 on the host here and in float32 inside
wp.grad) moves it by ~δθ/√v ≈ 1e-5 of ν. At the worst such points the closed form is the closer of the two to
the float64 finite difference (e.g. 11898.03 and 11895.92 against 11898.05 for ∂S_r/∂β_m).

S and the pdf returned with J must be the renderer's own (those of bsdf.eval and bsdf.pdf), bit for bit: the
gradient tracer follows the forward renderer's paths.
"""

import math
import warnings

import numpy as np
import pytest
import warp as wp
from helpers import bsdf_derivatives as fd
from helpers import bsdf_grad
from scipy.special import i0e, i1e

import warp_hair as wh
from warp_hair.model.hair_bsdf import HairCoefficients, hair_coefficients, incident, lobe_setup
from warp_hair.model.jacobian import (
    CoefficientDerivatives,
    coefficient_derivatives,
    hair_value_jacobian,
    hair_value_pdf_lobes,
    lobe_setup_grad,
    value_jacobian_mat,
)
from warp_hair.model.lobes import logistic_norm, longitudinal_norm
from warp_hair.model.params import BETA_FLOOR
from warp_hair.numerics import bessel_i0e_times_exp_with_log_slope

wp.set_module_options({"enable_backward": False})

EDGE_RTOL = 1e-3
EDGE_ATOL = 5e-5
INTERIOR_MATERIALS = 12
EDGE_MATERIALS = 24
CONFIGS_PER_MATERIAL = 256


@wp.kernel
def _jacobian_kernel(
    c: HairCoefficients,
    derivs: CoefficientDerivatives,
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    jacobian: wp.array(dtype=value_jacobian_mat),
    value: wp.array(dtype=wp.vec3),
    density: wp.array(dtype=float),
):
    i = wp.tid()
    setup = lobe_setup(c, wo[i], h[i])
    s, pdf, lobes = hair_value_pdf_lobes(setup, incident(setup, wi[i]))
    value[i] = s
    density[i] = pdf
    jacobian[i] = hair_value_jacobian(setup, lobe_setup_grad(setup, wo[i], h[i]), derivs, lobes)


def closed_form(params, wo, wi, h):
    """(J (N, 3, 8), S (N, 3), pdf (N,)) from bsdf_jacobian, in float32 as the kernel returns them."""
    n = len(h)
    J, S, pdf = wp.empty(n, dtype=value_jacobian_mat), wp.empty(n, dtype=wp.vec3), wp.empty(n, dtype=float)
    arrays = [wp.array(a, dtype=t) for a, t in ((wo, wp.vec3), (wi, wp.vec3), (h, float))]
    wp.launch(_jacobian_kernel, n, [hair_coefficients(params), coefficient_derivatives(params), *arrays, J, S, pdf])
    return J.numpy(), S.numpy(), pdf.numpy()


def reverse_mode(params, wo, wi, h):
    """(N, 3, 8): bsdf_grad.eval_grad's dict laid out in θ's columns."""
    g = bsdf_grad.eval_grad(params, wo, wi, h)
    J = np.zeros((len(h), 3, bsdf_grad.CONTROL_COUNT), dtype=np.float32)
    if params.colour_input == "melanin":
        J[:, :, 0], J[:, :, 1] = g["eumelanin"], g["pheomelanin"]
    else:
        J[:, :, 0:3] = g[params.colour_input]
    for name, column in bsdf_grad.SCALAR_CONTROLS.items():
        J[:, :, column] = g[name]
    return J


def natural_scales(controls: dict) -> np.ndarray:
    nu = np.ones(bsdf_grad.CONTROL_COUNT)
    for name, column in bsdf_grad.SCALAR_CONTROLS.items():
        nu[column] = fd.natural_scale(controls, name)
    return nu


def compare(controls, params, wo, wi, h, rtol, atol):
    """(worst |J − J_wp.grad| over its allowance (≤ 1 passes), worst relative difference where J_wp.grad is not
    near-stationary: |J_wp.grad| ≥ 0.1 |S| ν_k). Checks on the way that S and pdf are the renderer's."""
    J, S, pdf = closed_form(params, wo, wi, h)
    np.testing.assert_array_equal(S, wh.bsdf.eval(params, wo, wi, h))
    np.testing.assert_array_equal(pdf, wh.bsdf.pdf(params, wo, wi, h))
    assert np.all(np.isfinite(J))
    R = reverse_mode(params, wo, wi, h).astype(np.float64)
    scale = np.abs(S.astype(np.float64))[:, :, None] * natural_scales(controls)
    err = np.abs(J - R)
    worst = float(np.max(err / (rtol * np.abs(R) + atol * scale + fd.UNDERFLOW)))
    clean = (np.abs(R) >= 0.1 * scale) & (np.abs(R) > fd.UNDERFLOW)
    return worst, float(np.max(err[clean] / np.abs(R[clean]), initial=0.0))


def interior_comparison(mode):
    rng = np.random.default_rng(21 + fd.COLOUR_MODES.index(mode))
    results = []
    for _ in range(INTERIOR_MATERIALS):
        controls = fd.random_controls(rng, mode)
        params = wh.HairParams(**controls)
        wo, wi, h = fd.configurations(rng, params, CONFIGS_PER_MATERIAL)
        results.append(compare(controls, params, wo, wi, h, fd.RTOL, fd.ATOL))
    return np.max(results, axis=0)


@pytest.mark.parametrize("mode", fd.COLOUR_MODES)
def test_interior_matches_reverse_mode(mode):
    worst, relative = interior_comparison(mode)
    assert worst <= 1.0, (worst, relative)


def edge_controls(rng, mode):
    controls = fd.random_controls(rng, mode)
    controls["alpha"] = float(np.float32(rng.choice([-10.0, 10.0, rng.uniform(-10.0, 10.0)])))
    controls["eta"] = float(np.float32(rng.uniform(1.2, 2.0)))
    for name in ("beta_m", "beta_n"):
        choices = [1.01 * BETA_FLOOR, 1.2 * BETA_FLOOR, 0.99, 1.0, rng.uniform(BETA_FLOOR, 1.0)]
        controls[name] = float(np.float32(rng.choice(choices)))
    return controls


def towards_axis(rng, w):
    """w turned to within 1e-4 (in x) of ±x, the fiber axis: grazing."""
    w = w.astype(np.float64)
    w[:, 0] = np.sign(w[:, 0] + 1e-12) * (1.0 - rng.uniform(0.0, 1e-4, len(w)))
    w[:, 1:] *= np.sqrt((1.0 - w[:, 0] ** 2) / np.maximum((w[:, 1:] ** 2).sum(axis=1), 1e-30))[:, None]
    return w.astype(np.float32)


def edge_configurations(rng, params, n):
    """A quarter each: h = +1, h = −1, grazing wo, grazing wi; wi importance-sampled for half (at those wo, h)."""
    wo, wi, h = fd.configurations(rng, params, n)
    q = n // 4
    h[:q], h[q : 2 * q] = 1.0, -1.0
    wo[2 * q : 3 * q] = towards_axis(rng, wo[2 * q : 3 * q])
    wi[3 * q :] = towards_axis(rng, wi[3 * q :])
    sampled = rng.random(n) < 0.5
    wi[sampled] = wh.bsdf.sample(params, wo[sampled], h[sampled], rng.random((int(sampled.sum()), 3)))[0]
    return wo, wi, h


def edge_comparison(mode):
    rng = np.random.default_rng(31 + fd.COLOUR_MODES.index(mode))
    results = []
    for _ in range(EDGE_MATERIALS):
        controls = edge_controls(rng, mode)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            params = wh.HairParams(**controls)
        wo, wi, h = edge_configurations(rng, params, CONFIGS_PER_MATERIAL)
        results.append(compare(controls, params, wo, wi, h, EDGE_RTOL, EDGE_ATOL))
    return np.max(results, axis=0)


@pytest.mark.parametrize("mode", fd.COLOUR_MODES)
def test_edges_match_reverse_mode(mode):
    worst, relative = edge_comparison(mode)
    assert worst <= 1.0 and relative <= EDGE_RTOL, (worst, relative)


@pytest.mark.parametrize("mode", fd.COLOUR_MODES)
def test_matches_float64_finite_differences(mode):
    """test_bsdf_grad's comparison with the reference, for the closed form: the allowance wp.grad meets."""
    rng = np.random.default_rng(41 + fd.COLOUR_MODES.index(mode))
    for _ in range(8):
        controls = fd.random_controls(rng, mode)
        params = wh.HairParams(**controls)
        wo, wi, h = fd.configurations(rng, params, 96)
        J = closed_form(params, wo, wi, h)[0].astype(np.float64)
        for column, (name, component) in enumerate(fd.control_entries(controls)):
            if mode == "melanin" and column >= 2:
                column += 1  # θ[2] is the unused melanin slot
            d, terms, out = fd.reference_derivative(controls, name, component, wo, wi, h)
            scale = fd.natural_scale(controls, name)
            allowed = fd.RTOL * terms[:, :3] + fd.ATOL * np.abs(out[:, :3]) * scale + fd.UNDERFLOW
            assert np.all(np.abs(J[:, :, column] - d[:, :3]) <= allowed), (controls, name, component)


def test_roughness_floor_has_zero_derivative():
    """At or below the floor nothing depends on β, through the lobes or (albedo input) the absorption."""
    rng = np.random.default_rng(51)
    wo, wi = fd.configurations(rng, wh.HairParams(albedo=0.5), 256)[:2]
    h = rng.uniform(-1.0, 1.0, 256).astype(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        params = wh.HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.005, beta_n=BETA_FLOOR)
    J = closed_form(params, wo, wi, h)[0]
    assert np.all(J[:, :, 3] == 0.0) and np.all(J[:, :, 4] == 0.0)
    assert np.any(J[:, :, 5] != 0.0)


def _moved(controls: dict, name: str, component, delta: float) -> wh.HairParams:
    """The material with one control (one component of an RGB one) moved by delta."""
    value = controls[name]
    if component is None:
        value = value + delta
    else:
        value = list(value)
        value[component] += delta
    return wh.HairParams(**{**controls, name: value})


def _central(quantity, controls: dict, name: str, component=None, step: float = 1e-6):
    """d quantity(material)/d control, a float64 central difference."""
    up, down = _moved(controls, name, component, step), _moved(controls, name, component, -step)
    return (np.asarray(quantity(up)) - np.asarray(quantity(down))) / (2.0 * step)


def _log_slope(function, x: float, step: float = 1e-6) -> float:
    """d ln function(x)/d ln x, a float64 central difference."""
    return (math.log(function(x * math.exp(step))) - math.log(function(x * math.exp(-step)))) / (2.0 * step)


def test_coefficient_derivatives_match_central_differences():
    """The host's float64 derivatives of the material mappings against central differences of params.py."""
    rng = np.random.default_rng(52)
    for mode in fd.COLOUR_MODES:
        for _ in range(6):
            controls = fd.random_controls(rng, mode)
            params = wh.HairParams(**controls)
            k = coefficient_derivatives(params)
            colour = [entry for entry in fd.control_entries(controls) if entry[0] not in bsdf_grad.SCALAR_CONTROLS]
            d_colour = np.array(k.d_sigma_d_colour).reshape(3, 3)
            for column, (name, component) in enumerate(colour):
                expected = _central(lambda p: p.absorption, controls, name, component)
                np.testing.assert_allclose(d_colour[:, column], expected, rtol=1e-6, atol=1e-9)
            expected = _central(lambda p: p.absorption, controls, "beta_n")
            np.testing.assert_allclose(np.array(k.d_sigma_d_beta_n), expected, rtol=1e-5, atol=1e-9)
            expected = _central(lambda p: math.log(p.lobe_variances[1]), controls, "beta_m")
            np.testing.assert_allclose(k.d_log_v_d_beta_m, expected, rtol=1e-5)
            expected = _central(lambda p: math.log(p.lobe_variances[0]), controls, "r_roughness_scale")
            np.testing.assert_allclose(k.d_log_v_r_d_scale, expected, rtol=1e-5)
            expected = _central(lambda p: math.log(p.logistic_scale), controls, "beta_n")
            np.testing.assert_allclose(k.d_log_s_d_beta_n, expected, rtol=1e-5)
            expected = [_log_slope(longitudinal_norm, v) for v in params.lobe_variances]
            np.testing.assert_allclose(np.array(k.m_norm_log_slope), expected, rtol=1e-5, atol=1e-9)
            expected = _log_slope(logistic_norm, params.logistic_scale)
            np.testing.assert_allclose(k.n_norm_log_slope, expected, rtol=1e-5, atol=1e-9)


@wp.kernel
def _bessel_kernel(x: wp.array(dtype=float), y: float, value: wp.array(dtype=float), slope: wp.array(dtype=float)):
    i = wp.tid()
    v, s = bessel_i0e_times_exp_with_log_slope(x[i], y)
    value[i] = v
    slope[i] = s


@pytest.mark.parametrize("y", [0.0, -0.7, -40.0])
def test_bessel_value_and_log_slope(y):
    """I0(x) e^(−x) e^y and d ln I0e/dx of the polynomial forms against scipy's i0e and I1/I0 − 1, through the
    branch switch, with M's other exponent y folded into the one exponential. The value's bound: the polynomials'
    5e-7 and the exponential's rounding, plus float32's rounding of the exponent y − x below the switch
    (2^−24 |y − x| relative: what rounding y itself already costs M)."""
    x = np.concatenate([np.linspace(0.0, 3.75, 2000, endpoint=False), np.geomspace(3.75, 1e6, 2000)]).astype(np.float32)
    value = wp.empty(len(x), dtype=float)
    slope = wp.empty(len(x), dtype=float)
    wp.launch(_bessel_kernel, len(x), [wp.array(x, dtype=float), y, value, slope])
    x64 = x.astype(np.float64)
    exponent_rounding = 2.0**-24 * (abs(y) + np.where(x64 < 3.75, x64, 0.0))
    relative = np.abs(value.numpy() / (i0e(x64) * np.exp(np.float32(y))) - 1.0)
    assert np.all(relative <= 6e-7 + exponent_rounding), relative.max()
    np.testing.assert_allclose(slope.numpy(), i1e(x64) / i0e(x64) - 1.0, rtol=1e-5)


if __name__ == "__main__":
    print(f"{'mode':8s} {'set':9s} {'worst / allowance':>18s} {'max rel. (not near-stationary)':>31s}")
    for mode in fd.COLOUR_MODES:
        for name, comparison in (("interior", interior_comparison), ("edges", edge_comparison)):
            worst, relative = comparison(mode)
            print(f"{mode:8s} {name:9s} {worst:18.3f} {relative:31.2e}")


# Positive over [0.01, 1], with a steep P' (P(0) = 4, P(1) = 3.5, P'(0) = 3): the absorption path of ∂/∂β_n
# differs clearly from the talk's polynomial's.
CUSTOM_INVERSION = [4.0, 3.0, -6.0, 2.0, 1.0, -0.5]


def test_custom_albedo_inversion_matches_finite_differences():
    """With an albedo input and custom inversion coefficients, ∂S/∂albedo and ∂S/∂β_n of the closed form and of
    wp.grad both meet test_bsdf_grad's allowance against five-point differences of the float64 reference (which
    applies the same coefficients), and the host's ∂σ_a/∂β_n is the central difference of HairParams.absorption."""
    rng = np.random.default_rng(61)
    entries = [("albedo", 0), ("albedo", 1), ("albedo", 2), ("beta_n", None)]
    columns = [0, 1, 2, bsdf_grad.BETA_N]
    for _ in range(6):
        controls = {**fd.random_controls(rng, "albedo"), "albedo_inversion": CUSTOM_INVERSION}
        params = wh.HairParams(**controls)
        assert params.albedo_inversion == tuple(CUSTOM_INVERSION)
        wo, wi, h = fd.configurations(rng, params, 96)
        J = closed_form(params, wo, wi, h)[0].astype(np.float64)
        R = reverse_mode(params, wo, wi, h).astype(np.float64)
        for (name, component), column in zip(entries, columns):
            d, terms, out = fd.reference_derivative(controls, name, component, wo, wi, h)
            scale = fd.natural_scale(controls, name)
            allowed = fd.RTOL * terms[:, :3] + fd.ATOL * np.abs(out[:, :3]) * scale + fd.UNDERFLOW
            for derivative in (J, R):
                assert np.all(np.abs(derivative[:, :, column] - d[:, :3]) <= allowed), (controls, name, component)
        k = coefficient_derivatives(params)
        expected = _central(lambda p: p.absorption, controls, "beta_n")
        np.testing.assert_allclose(np.array(k.d_sigma_d_beta_n), expected, rtol=1e-5, atol=1e-9)
        talk = coefficient_derivatives(params.replace(albedo_inversion=wh.model.params.TALK_ALBEDO_INVERSION))
        assert not np.allclose(np.array(talk.d_sigma_d_beta_n), expected, rtol=1e-2)
