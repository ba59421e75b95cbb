"""Derivatives of S and pdf with respect to every artist control (tests/helpers/bsdf_grad.py) against the reference.

The reference derivative d of each output (S_r, S_g, S_b, pdf) is a five-point central finite difference of
the float64 NumPy model (tests/helpers/reference_model.py), step 1e-5 of the control's scale (steps of 5e-6 and
2e-5 change it by less than 1e-3 of the allowance below: truncation and rounding are negligible). Each
output is a sum over the lobes p of a geometric factor G_p = M_p N_p times a colour factor F_p (A_p for S,
the lobe probability for the pdf), and no control acts on both M and N, so d = Σ_p (∂G_p F_p + G_p ∂F_p).
An entry passes when

    |g − d| ≤ RTOL · Σ_p (|∂G_p F_p| + |G_p ∂F_p|) + ATOL · |out| · ν_k + UNDERFLOW.

RTOL = 1e-4 is relative to the magnitudes of the terms that are summed, not to their sum: the lobes and
factors cancel one another (the tilt moves R one way and TRT the other, a rougher lobe loses at its peak what
it gains in its tails), and a float32 sum of terms carries their rounding, whatever is left of the total.

ATOL bounds the error of ∂ log(out)/∂θ_k in units of ν_k, the natural log-scale of the control (how fast
it reshapes the lobe it drives; `natural_scale`). It is for entries that are near-stationary inside one
factor, where the derivative is the difference of parts each ~ν_k large and float32 leaves ~1e-7 ν_k of it.
The longitudinal lobes are where this shows: for a narrow lobe (large a = cos θ_i cos θ_o / v)
∂ log M/∂v ≈ 1/2v − 1/v − (cos(θ_i + θ_o) − 1)/v², which passes through 0 where the lobe bends (as
∂ log M/∂θ_o does at its peak), while cos(θ_i + θ_o) − 1 comes from float32 angles (the tilt rotation of wo,
~1e-7 rad):
1e-5 relative at a 1σ offset of a β_m = 0.04 lobe, an error the forward value carries as well. Measured over
these 424 000 entries: with ATOL = 1e-6, 44 exceed (worst 3×), all on β_m, r_roughness_scale and α at such
points; ATOL = 1e-5 leaves a margin of 2×. Where the derivative is no cancellation (|d| at least half its
terms and |∂ log out/∂θ_k| ≥ 0.1 ν_k) the plain relative error stays below 1e-4 (6e-5 measured).
UNDERFLOW: below 1e-30 float32 values are subnormal or 0, and so are their derivatives.

Controls are rounded to float32 before both sides see them (the kernels read float32 controls, as they read
float32 directions): otherwise the rounding of η moves the azimuthal centres by 1e-7 rad, which near the
peak of a narrow logistic changes ∂N/∂η by 1e-2 relative and would be charged to the derivative.
Configurations: random controls in the interior of their ranges (β ≥ 0.02, twice the roughness floor), wo
uniform, |h| < 0.999, wi uniform for half of them and importance-sampled for the other half (where S is
large, including the peaks of narrow lobes).

`python tests/test_bsdf_grad.py` prints the largest errors per colour mode and control.
"""

import warnings

import numpy as np
import pytest
import warp as wp
from helpers import bsdf_grad
from helpers.bsdf_derivatives import (
    ATOL,
    COLOUR_MODES,
    RTOL,
    UNDERFLOW,
    configurations,
    control_entries,
    natural_scale,
    random_controls,
    reference_derivative,
)
from helpers.sphere import random_directions

import warp_hair as wh
from warp_hair.model.hair_bsdf import HairCoefficients, hair_coefficients
from warp_hair.model.params import TALK_ALBEDO_INVERSION, sigma_a_from_albedo

wp.set_module_options({"enable_backward": False})

MATERIALS_PER_MODE = 48
CONFIGS_PER_MATERIAL = 96  # 4608 configurations per colour mode


def warp_derivative(value_grad: dict, pdf_grad: dict, name: str, component) -> np.ndarray:
    """(N, 4): ∂(S_r, S_g, S_b, pdf)/∂ one scalar control, from the batch API's dicts."""
    if component is None:
        return np.concatenate([value_grad[name], pdf_grad[name][:, None]], axis=1)
    return np.concatenate([value_grad[name][:, :, component], pdf_grad[name][:, component : component + 1]], axis=1)


def compare_mode(mode: str, seed: int = 7) -> dict:
    """For one colour mode, per control entry: the worst excess (≤ 1 passes) with where it happened, and
    the largest plain relative error over the well-conditioned entries: |d| at least half its terms, and
    |∂ log out/∂θ| ≥ 0.1 ν (so the absolute allowance is at most RTOL of it)."""
    rng = np.random.default_rng(seed + COLOUR_MODES.index(mode))
    results = {}
    for _material in range(MATERIALS_PER_MODE):
        controls = random_controls(rng, mode)
        params = wh.HairParams(**controls)
        wo, wi, h = configurations(rng, params, CONFIGS_PER_MATERIAL)
        value_grad = bsdf_grad.eval_grad(params, wo, wi, h)
        pdf_grad = bsdf_grad.pdf_grad(params, wo, wi, h)
        for name, component in control_entries(controls):
            g = warp_derivative(value_grad, pdf_grad, name, component).astype(np.float64)
            d, terms, out = reference_derivative(controls, name, component, wo, wi, h)
            absolute = ATOL * np.abs(out) * natural_scale(controls, name)
            err = np.abs(g - d)
            excess = err / (RTOL * terms + absolute + UNDERFLOW)
            clean = (np.abs(d) >= 0.5 * terms) & (np.abs(d) >= 1e4 * absolute) & (np.abs(out) > 1e-20)
            key = name if component is None else f"{name}[{'rgb'[component]}]"
            r = results.setdefault(key, {"excess": 0.0, "relative": 0.0, "where": None})
            if clean.any():
                r["relative"] = max(r["relative"], float(np.max(err[clean] / np.abs(d[clean]))))
            i, o = np.unravel_index(np.argmax(excess), excess.shape)
            if excess[i, o] > r["excess"]:
                r["excess"] = float(excess[i, o])
                r["where"] = {
                    "controls": controls,
                    "wo": wo[i],
                    "wi": wi[i],
                    "h": h[i],
                    "output": int(o),
                    "warp": g[i, o],
                    "reference": d[i, o],
                }
    return results


@pytest.fixture(scope="module", params=COLOUR_MODES)
def comparison(request):
    return request.param, compare_mode(request.param)


def test_derivatives_match_finite_differences_of_the_reference(comparison):
    mode, results = comparison
    assert len(results) == {"albedo": 8, "sigma_a": 8, "melanin": 7}[mode]
    bad = {key: r for key, r in results.items() if not r["excess"] <= 1.0}
    assert not bad, f"{mode}: tolerance exceeded: {bad}"


def _material_pairs(rng, n):
    """(albedo params, the same σ_a given directly) with random scalar controls."""
    for _ in range(n):
        controls = random_controls(rng, "albedo")
        with_albedo = wh.HairParams(**controls)
        yield controls, with_albedo, with_albedo.replace(sigma_a=list(with_albedo.absorption))


def _sigma_a_slopes(controls, step=1e-6):
    """∂σ_a/∂β_n and ∂σ_a/∂albedo (diagonal), both (3,), of the albedo inversion in float64."""
    albedo, beta_n = np.array(controls["albedo"]), controls["beta_n"]
    p = controls.get("albedo_inversion", TALK_ALBEDO_INVERSION)
    d_beta_n = (sigma_a_from_albedo(albedo, beta_n + step, p) - sigma_a_from_albedo(albedo, beta_n - step, p)) / (
        2 * step
    )
    h = step * albedo
    d_albedo = (sigma_a_from_albedo(albedo + h, beta_n, p) - sigma_a_from_albedo(albedo - h, beta_n, p)) / (2 * h)
    return d_beta_n, d_albedo


def test_albedo_input_adds_exactly_the_absorption_path():
    """With an albedo input, ∂/∂β_n = ∂/∂β_n at the same σ_a given directly + Σ_c ∂/∂σ_c ∂σ_c/∂β_n, and
    ∂/∂albedo_c = ∂/∂σ_c ∂σ_c/∂albedo_c: the inversion's chain, for S and for the pdf. The absorption path
    must be a real part of ∂/∂β_n (else the check would be vacuous)."""
    rng = np.random.default_rng(11)
    share = []
    for controls, with_albedo, with_sigma in _material_pairs(rng, 24):
        wo, wi, h = configurations(rng, with_albedo, 256)
        d_beta_n, d_albedo = _sigma_a_slopes(controls)
        nu = natural_scale(controls, "beta_n")
        for grad, evaluate in ((bsdf_grad.eval_grad, wh.bsdf.eval), (bsdf_grad.pdf_grad, wh.bsdf.pdf)):
            ga, gs = grad(with_albedo, wo, wi, h), grad(with_sigma, wo, wi, h)
            out = np.abs(evaluate(with_sigma, wo, wi, h))
            absorption_path = gs["sigma_a"] @ d_beta_n
            lhs = ga["beta_n"] - gs["beta_n"]
            allowed = (
                RTOL * (np.abs(ga["beta_n"]) + np.abs(gs["beta_n"]) + np.abs(absorption_path))
                + ATOL * out * nu
                + UNDERFLOW
            )
            assert np.all(np.abs(lhs - absorption_path) <= allowed)
            # The same allowance as the reference comparison, with ν = 1 per unit σ_a carried through ∂σ_a/∂albedo.
            albedo_path = gs["sigma_a"] * d_albedo
            allowed = RTOL * np.abs(albedo_path) + ATOL * out[..., None] * np.abs(d_albedo) + UNDERFLOW
            assert np.all(np.abs(ga["albedo"] - albedo_path) <= allowed)
            share.append(np.abs(absorption_path) / (np.abs(gs["beta_n"]) + np.abs(absorption_path) + UNDERFLOW))
    share = np.concatenate([s.ravel() for s in share])
    assert np.mean(share > 0.1) > 0.1  # measured: above 10 % of ∂/∂β_n in 22 % of the entries, above half in 8 %


def test_roughness_floor_has_zero_derivative():
    """β below the floor renders as the floor, so nothing depends on it there, through the lobes or σ_a."""
    rng = np.random.default_rng(12)
    wo, wi = random_directions(rng, 512), random_directions(rng, 512)
    h = rng.uniform(-0.999, 0.999, 512)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        params = wh.HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.005, beta_n=0.0)
    for grad in (bsdf_grad.eval_grad, bsdf_grad.pdf_grad):
        g = grad(params, wo, wi, h)
        assert np.all(g["beta_m"] == 0.0) and np.all(g["beta_n"] == 0.0)
        assert np.any(g["alpha"] != 0.0)


# A module of its own: see bsdf_grad's docstring on forward-only callers of the mappings.
@wp.kernel(module="unique")
def _coefficients_kernel(controls: bsdf_grad.HairControls, out: wp.array(dtype=HairCoefficients)):
    out[0] = bsdf_grad.coefficients_from_controls(controls.theta, controls.colour_mode, controls.albedo_inversion)


def test_warp_mappings_build_the_host_coefficients():
    """coefficients_from_controls (Warp, float32) = hair_coefficients (host, float64), field by field."""
    rng = np.random.default_rng(13)
    for mode in COLOUR_MODES:
        for _ in range(8):
            params = wh.HairParams(**random_controls(rng, mode))
            out = wp.empty(1, dtype=HairCoefficients)
            wp.launch(_coefficients_kernel, 1, [bsdf_grad.hair_controls(params), out])
            host = hair_coefficients(params)
            for field in HairCoefficients.vars:
                if field not in ("n_tail", "cone"):  # sampling only; not built for derivatives
                    warp_value, host_value = out.numpy()[field][0], np.array(getattr(host, field))
                    np.testing.assert_allclose(warp_value, host_value, rtol=2e-6, atol=1e-7, err_msg=field)


@wp.kernel
def _jacobian_kernel(
    controls: bsdf_grad.HairControls,
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    seed: wp.array(dtype=wp.vec4),
    jacobian: wp.array(dtype=bsdf_grad.jacobian_mat),
    vjp: wp.array(dtype=bsdf_grad.controls_vec),
):
    i = wp.tid()
    jacobian[i] = bsdf_grad.hair_value_pdf_jacobian(controls, wo[i], wi[i], h[i])
    vjp[i] = bsdf_grad.hair_value_pdf_vjp(controls, wo[i], wi[i], h[i], seed[i])


def test_kernel_functions_agree_with_the_batch_api():
    """The Jacobian's rows are what eval_grad/pdf_grad return (theta ordering of the module docstring); a
    vector-Jacobian product with any seed is seedᵀ J; the unused melanin slot has derivative 0."""
    rng = np.random.default_rng(14)
    n = 256
    for mode in COLOUR_MODES:
        controls = random_controls(rng, mode)
        params = wh.HairParams(**controls)
        wo, wi, h = configurations(rng, params, n)
        seed = rng.normal(size=(n, 4)).astype(np.float32)
        J = wp.empty(n, dtype=bsdf_grad.jacobian_mat)
        vjp = wp.empty(n, dtype=bsdf_grad.controls_vec)
        arrays = [wp.array(a, dtype=t) for a, t in ((wo, wp.vec3), (wi, wp.vec3), (h, float), (seed, wp.vec4))]
        wp.launch(_jacobian_kernel, n, [bsdf_grad.hair_controls(params), *arrays, J, vjp])
        J, vjp = J.numpy(), vjp.numpy()
        value_grad, pdf_grad = bsdf_grad.eval_grad(params, wo, wi, h), bsdf_grad.pdf_grad(params, wo, wi, h)
        for name, column in bsdf_grad.SCALAR_CONTROLS.items():
            np.testing.assert_array_equal(J[:, :3, column], value_grad[name])
            np.testing.assert_array_equal(J[:, 3, column], pdf_grad[name])
        if mode == "melanin":
            np.testing.assert_array_equal(J[:, :3, 0], value_grad["eumelanin"])
            np.testing.assert_array_equal(J[:, :3, 1], value_grad["pheomelanin"])
            assert np.all(J[:, :, 2] == 0.0)
        else:
            np.testing.assert_array_equal(J[:, :3, :3], value_grad[mode])
            np.testing.assert_array_equal(J[:, 3, :3], pdf_grad[mode])
        # The rows are rounded in different orders: the reference comparison's allowance, applied per row.
        expected = np.einsum("nr,nrk->nk", seed.astype(np.float64), J)
        out = np.concatenate([wh.bsdf.eval(params, wo, wi, h), wh.bsdf.pdf(params, wo, wi, h)[:, None]], axis=1)
        nu = np.ones(bsdf_grad.CONTROL_COUNT)
        for name, column in bsdf_grad.SCALAR_CONTROLS.items():
            nu[column] = natural_scale(controls, name)
        per_row = np.abs(seed)[:, :, None] * (RTOL * np.abs(J) + ATOL * np.abs(out)[:, :, None] * nu)
        assert np.all(np.abs(vjp - expected) <= per_row.sum(axis=1) + UNDERFLOW)


def test_shapes_and_names():
    rng = np.random.default_rng(15)
    wo, wi = random_directions(rng, 5), random_directions(rng, 5)
    for controls, colour_keys in (
        ({"albedo": [0.6, 0.4, 0.2]}, {"albedo": (5, 3, 3)}),
        ({"sigma_a": 0.3}, {"sigma_a": (5, 3, 3)}),
        ({"eumelanin": 1.3}, {"eumelanin": (5, 3), "pheomelanin": (5, 3)}),
    ):
        params = wh.HairParams(**controls)
        value_grad, pdf_grad = bsdf_grad.eval_grad(params, wo, wi, 0.3), bsdf_grad.pdf_grad(params, wo, wi, 0.3)
        scalars = dict.fromkeys(bsdf_grad.SCALAR_CONTROLS, (5, 3))
        assert {k: v.shape for k, v in value_grad.items()} == {**colour_keys, **scalars}
        assert {k: v.shape for k, v in pdf_grad.items()} == {
            k: s[:1] + s[2:] for k, s in {**colour_keys, **scalars}.items()
        }
    # A single direction and a scalar h broadcast like bsdf.eval; the split over threads changes nothing.
    assert bsdf_grad.eval_grad(params, wo[0], wi, 0.0)["beta_m"].shape == (5, 3)
    one, two = bsdf_grad.pdf_grad(params, wo, wi, 0.3, threads=1), bsdf_grad.pdf_grad(params, wo, wi, 0.3, threads=2)
    assert all(np.array_equal(one[k], two[k]) for k in one)


def test_extremes_are_finite():
    """h = ±1, grazing and axis directions, β at the floor and 1, albedo 1, extreme R scales: no NaN or Inf."""
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    wo, wi = np.repeat(axes, 6, axis=0), np.tile(axes, (6, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        materials = [
            wh.HairParams(albedo=a, beta_m=bm, beta_n=bn, r_roughness_scale=k, alpha=30.0)
            for a in (1.0, 1e-6)
            for bm in (0.0, 1.0)
            for bn in (0.0, 1.0)
            for k in (1e-3, 1e3)
        ] + [wh.HairParams(eumelanin=8.0, eta=1.0001), wh.HairParams(sigma_a=0.0, eta=10.0)]
    for params in materials:
        for h in (-1.0, 0.0, 1.0):
            for grad in (bsdf_grad.eval_grad, bsdf_grad.pdf_grad):
                for name, g in grad(params, wo, wi, h).items():
                    assert np.all(np.isfinite(g)), (params, h, name)


Z = [0.0, 0.0, 1.0]


@pytest.mark.parametrize(
    "grad,params,wo,wi,h,extra,error,pattern",
    [
        (bsdf_grad.eval_grad, {"albedo": 0.5}, Z, Z, 0.0, {}, TypeError, r"params must be a warp_hair.HairParams"),
        (
            bsdf_grad.eval_grad,
            wh.HairParams(albedo=0.5),
            np.zeros((4, 2)),
            Z,
            0.0,
            {},
            ValueError,
            r"wo must have shape",
        ),
        (
            bsdf_grad.pdf_grad,
            wh.HairParams(albedo=0.5),
            Z,
            [0, 0, 2],
            0.0,
            {},
            ValueError,
            r"wi must hold unit vectors",
        ),
        (bsdf_grad.pdf_grad, wh.HairParams(albedo=0.5), Z, Z, 1.5, {}, ValueError, r"h must lie in \[-1, 1\]"),
        (
            bsdf_grad.eval_grad,
            wh.HairParams(albedo=0.5),
            Z,
            Z,
            0.0,
            {"threads": 0},
            ValueError,
            r"threads must be at least 1",
        ),
    ],
)
def test_bad_input_is_rejected_like_bsdf_eval(grad, params, wo, wi, h, extra, error, pattern):
    with pytest.raises(error, match=pattern):
        grad(params, wo, wi, h, **extra)


if __name__ == "__main__":
    print(f"{'mode':8s} {'control':20s} {'max excess':>10s} {'max rel. err (well-conditioned)':>32s}")
    for mode in COLOUR_MODES:
        for key, r in compare_mode(mode).items():
            print(f"{mode:8s} {key:20s} {r['excess']:10.3f} {r['relative']:32.2e}")
