"""Bad input gets an error that names the problem; the edges of the valid range give finite values."""

import re
import warnings

import numpy as np
import pytest

import warp_hair as wh
from warp_hair.model.params import HairParams


@pytest.mark.parametrize(
    "controls,pattern",
    [
        ({"albedo": [0.5, 1.2, 0.5]}, r"albedo\[g\] = 1.2 is outside the allowed range \(0.0, 1.0\]"),
        ({"albedo": 0.0}, r"albedo\[r\] = 0.0 is outside the allowed range \(0.0, 1.0\]"),
        ({"albedo": [0.5, 0.5]}, r"albedo must be one number or three"),
        ({"sigma_a": [-0.1, 0.0, 0.0]}, r"sigma_a\[r\] = -0.1 is outside the allowed range \[0.0, 1e\+30\]"),
        ({"eumelanin": -1.0}, r"eumelanin = -1.0 is outside the allowed range"),
        ({"albedo": 0.5, "beta_m": 1.5}, r"beta_m = 1.5 is outside the allowed range \[0.0, 1.0\]"),
        ({"albedo": 0.5, "beta_n": -0.2}, r"beta_n = -0.2 is outside the allowed range \[0.0, 1.0\]"),
        ({"albedo": 0.5, "alpha": 45.0}, r"alpha = 45.0 is outside the allowed range \[-30.0, 30.0\]"),
        ({"albedo": 0.5, "eta": 1.0}, r"eta = 1.0 is outside the allowed range \(1.0, 10.0\]"),
        # Above 1 in float64 but 1 in float32, where the kernels evaluate the BSDF.
        (
            {"albedo": 0.5, "eta": 1.000000001},
            r"eta = 1.000000001 is outside .*\(1.0, 10.0\] in float32.*rounds to 1.0",
        ),
        # Nested lists are not flattened: the key is named.
        ({"albedo": [[0.5, 0.5, 0.5]]}, r"albedo must be one number or three \(RGB\), in a flat list"),
        ({"sigma_a": [[0.5], [0.5], [0.5]]}, r"sigma_a must be one number or three \(RGB\), in a flat list"),
        ({"sigma_a": [0.5, [0.5], 0.5]}, r"sigma_a\[g\] must be a number"),
        (
            {"albedo": 0.5, "r_roughness_scale": 0.0},
            r"r_roughness_scale = 0.0 is outside the allowed range \[1e-06, 1000000.0\]",
        ),
        ({"albedo": 0.5, "beta_m": float("nan")}, r"beta_m must be finite"),
        ({"albedo": 0.5, "eta": "glass"}, r"eta must be a number, got 'glass'"),
        ({}, r"exactly one colour input.*got none"),
        ({"albedo": 0.5, "sigma_a": 0.1}, r"exactly one colour input.*got albedo, sigma_a"),
        ({"sigma_a": 0.1, "eumelanin": 1.0}, r"exactly one colour input.*got sigma_a, eumelanin/pheomelanin"),
    ],
)
def test_bad_controls_name_the_parameter(controls, pattern):
    with pytest.raises(ValueError, match=pattern):
        HairParams(**controls)


def test_eta_is_checked_in_float32_where_the_bsdf_is_finite():
    """The kernels read η as float32. At float32 η = 1 the Fresnel reflectance is 0, so a strongly absorbing fiber
    has no lobe left and the lobe-selection pdf is 0/0: that is why the range (1, 10] is checked in float32. At
    the smallest η it accepts (the float32 just above 1) every value is finite."""
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0], [0.3, 0.4, 0.866], [0, -0.6, -0.8]])
    wo, wi = np.repeat(axes, len(axes), axis=0), np.tile(axes, (len(axes), 1))
    u = np.random.default_rng(0).uniform(size=(len(wo), 3))
    smallest = float(np.nextafter(np.float32(1.0), np.float32(2.0)))

    def values(eta):
        params = HairParams(eumelanin=1e6, pheomelanin=8.0, eta=smallest)
        object.__setattr__(params, "eta", eta)  # past the check, to show what it guards
        h = 0.0
        return [wh.bsdf.eval(params, wo, wi, h), wh.bsdf.pdf(params, wo, wi, h), *wh.bsdf.sample(params, wo, h, u)]

    assert all(np.isfinite(a).all() for a in values(smallest))
    assert not all(np.isfinite(a).all() for a in values(1.0 + 1e-9))
    with pytest.raises(ValueError, match=r"eta = 1.000000001 .* in float32"):
        HairParams(eumelanin=1e6, pheomelanin=8.0, eta=1.0 + 1e-9)


def test_roughness_below_the_floor_warns_and_renders_as_the_floor():
    with pytest.warns(UserWarning, match=r"beta_m = 0.0 is below 0.01"):
        zero = HairParams(albedo=0.5, beta_m=0.0)
    np.testing.assert_array_equal(zero.lobe_variances, HairParams(albedo=0.5, beta_m=0.01).lobe_variances)


def test_dict_round_trip_and_unknown_keys():
    for params in (
        HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.25, alpha=3.0),
        HairParams(sigma_a=0.3, r_roughness_scale=2.0),
        HairParams(eumelanin=1.3, pheomelanin=0.2, eta=1.6),
    ):
        assert HairParams.from_dict(params.to_dict()) == params
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['beta'\] in scene.toml \[hair\]"):
        HairParams.from_dict({"albedo": 0.5, "beta": 0.3}, where="scene.toml [hair]")
    assert HairParams(albedo=0.5).replace(sigma_a=0.2).colour_input == "sigma_a"


PARAMS = HairParams(albedo=[0.6, 0.4, 0.2])
WO = np.array([[0.0, 0.0, 1.0]])


@pytest.mark.parametrize(
    "call,pattern",
    [
        (
            lambda: wh.bsdf.eval(PARAMS, np.zeros((4, 2)), WO, 0.0),
            r"wo must have shape \(N, 3\) or \(3,\), got \(4, 2\)",
        ),
        (
            lambda: wh.bsdf.eval(PARAMS, WO, [[0.0, 0.0, 2.0]], 0.0),
            r"wi must hold unit vectors .* wi\[0\] has length 2",
        ),
        (lambda: wh.bsdf.eval(PARAMS, WO, WO, 1.5), r"h must lie in \[-1, 1\]; h\[0\] = 1.5"),
        (lambda: wh.bsdf.pdf(PARAMS, WO, [[np.nan, 0.0, 1.0]], 0.0), r"wi contains NaN or Inf"),
        (lambda: wh.bsdf.pdf(PARAMS, WO, WO, [0.0, np.inf]), r"h contains NaN or Inf"),
        (lambda: wh.bsdf.sample(PARAMS, WO, 0.0, [[0.5, 1.0, 0.5]]), r"u must lie in \[0, 1\); u\[0, 1\] = 1.0"),
        (
            lambda: wh.bsdf.sample(PARAMS, WO, 0.0, np.zeros((5, 2))),
            r"u must have shape \(N, 3\) or \(3,\), got \(5, 2\)",
        ),
        (
            lambda: wh.bsdf.eval(PARAMS, np.tile(WO, (3, 1)), np.tile(WO, (2, 1)), 0.0),
            r"different lengths \(wo: 3, wi: 2, h: 1\); wi must have length 1 or 3",
        ),
        (lambda: wh.bsdf.eval(PARAMS, WO, WO, [[0.0]]), r"h must be a scalar or have shape \(N,\)"),
        (lambda: wh.bsdf.eval(PARAMS, WO, WO, 0.0, threads=0), r"threads must be at least 1"),
        (lambda: wh.bsdf.eval(PARAMS, WO, "up", 0.0), r"wi must be numeric"),
    ],
)
def test_bad_arrays_name_the_problem(call, pattern):
    with pytest.raises(ValueError, match=pattern):
        call()


def test_params_must_be_hair_params():
    with pytest.raises(TypeError, match=re.escape("params must be a warp_hair.HairParams, got dict")):
        wh.bsdf.eval({"albedo": 0.5}, WO, WO, 0.0)


def test_extremes_are_finite():
    """Every combination of the edges: finite, non-negative values and no NaN anywhere."""
    axes = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    wo = np.repeat(axes, len(axes), axis=0)
    wi = np.tile(axes, (len(axes), 1))
    u_edges = np.array([[0.0, 0.0, 0.0], [1 - 2**-24] * 3, [0.0, 1 - 2**-24, 0.5], [0.5, 0.0, 1 - 2**-24]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        materials = [
            HairParams(albedo=a, beta_m=bm, beta_n=bn, r_roughness_scale=k)
            for a in (1.0, 1e-6)
            for bm in (0.0, 1.0)
            for bn in (0.0, 1.0)
            for k in (1e-3, 1.0, 1e3)
        ]
    for params in materials:
        for h in (-1.0, 0.0, 1.0):
            assert np.all(np.isfinite(wh.bsdf.eval(params, wo, wi, h)))
            assert np.all(wh.bsdf.eval(params, wo, wi, h) >= 0.0)
            assert np.all(np.isfinite(wh.bsdf.pdf(params, wo, wi, h)))
            for u in u_edges:
                w, weight, density = wh.bsdf.sample(params, wo, h, u)
                assert np.all(np.isfinite(w)) and np.all(np.isfinite(weight)) and np.all(np.isfinite(density))
                np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-5)
                assert np.all(weight >= 0.0)
