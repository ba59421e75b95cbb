"""The Warp BSDF agrees with an independent float64 NumPy reference (tests/helpers/reference_model.py).

Tolerance: 1e-4 relative or 1e-6 absolute per value (|warp − ref| ≤ 1e-4·|ref| + 1e-6); a sampled
direction is a unit vector, so its relative error is |wi_warp − wi_ref|. 24 materials × 512 configurations
(12 288 in all), drawn at random and with the edges placed on purpose: h = ±1 and 0, grazing directions
(sin θ = ±1), β at 0 and 1, albedo 1 (σ_a = 0), dense absorption, extreme R-roughness scales, tilts and
indices of refraction, uniforms at 0 and just below 1.
"""

import warnings

import numpy as np
import pytest
from helpers import reference_model as ref
from helpers.sphere import random_directions

import warp_hair as wh

RTOL, ATOL = 1e-4, 1e-6
UNDERFLOW = 1e-30
PER_MATERIAL = 512

MATERIALS = [
    {"albedo": [0.6, 0.4, 0.2]},
    {"albedo": 1.0},
    {"sigma_a": 0.0, "beta_m": 0.0, "beta_n": 0.0},
    {"sigma_a": 0.0, "beta_m": 1.0, "beta_n": 1.0},
    {"sigma_a": 0.0, "beta_m": 0.0, "beta_n": 1.0},
    {"sigma_a": 0.0, "beta_m": 1.0, "beta_n": 0.0},
    {"albedo": [0.9, 0.8, 0.7], "beta_m": 0.1, "beta_n": 0.1},
    {"albedo": [0.05, 0.04, 0.03], "beta_m": 0.7, "beta_n": 0.9},
    {"sigma_a": [0.1444, 0.2491, 0.516]},
    {"sigma_a": [20.0, 50.0, 100.0], "beta_m": 0.2},
    {"eumelanin": 8.0},
    {"eumelanin": 0.3, "pheomelanin": 0.1, "beta_m": 0.25, "beta_n": 0.35},
    {"pheomelanin": 3.0, "beta_m": 0.6, "beta_n": 0.2},
    {"albedo": 0.5, "alpha": 0.0},
    {"albedo": 0.5, "alpha": 30.0, "beta_m": 0.05},
    {"albedo": 0.5, "alpha": -30.0, "beta_m": 0.4},
    {"albedo": 0.5, "eta": 1.01},
    {"albedo": 0.5, "eta": 2.5, "beta_n": 0.6},
    {"albedo": 0.7, "r_roughness_scale": 1e-3, "beta_m": 0.3},
    {"albedo": 0.7, "r_roughness_scale": 100.0, "beta_m": 0.3},
    {"albedo": 0.3, "r_roughness_scale": 0.2, "beta_m": 0.02, "beta_n": 0.05},
    {"sigma_a": 0.0, "beta_m": 0.5, "beta_n": 0.5, "alpha": 10.0},
    {"albedo": [0.99, 0.5, 0.01], "beta_m": 0.9, "beta_n": 0.05},
    {"sigma_a": 0.25, "beta_m": 0.3, "beta_n": 0.3, "alpha": 5.0, "eta": 1.3},
]

EDGE_DIRECTIONS = np.array(
    [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]
)


def configurations(rng, n):
    """n random (wo, wi, h, u) with the edge values mixed in."""
    wo, wi = random_directions(rng, n), random_directions(rng, n)
    h = rng.uniform(-1.0, 1.0, n)
    u = rng.random((n, 3))
    k = len(EDGE_DIRECTIONS)
    wo[:k] = EDGE_DIRECTIONS
    wi[k : 2 * k] = EDGE_DIRECTIONS
    wo[2 * k : 3 * k] = EDGE_DIRECTIONS
    wi[2 * k : 3 * k] = -EDGE_DIRECTIONS  # grazing in, grazing out
    h[: n // 8] = rng.choice([-1.0, 0.0, 1.0], n // 8)
    u[n // 8 : n // 4] = rng.choice([0.0, 1.0 - 2.0**-24, 0.5], (n // 4 - n // 8, 3))
    # Float32 inputs, as the renderer would pass them; the reference reads the very same numbers.
    return (
        wo.astype(np.float32),
        wi.astype(np.float32),
        h.astype(np.float32),
        u.astype(np.float32),
    )


def relative_excess(warp_value, ref_value):
    """max of |warp − ref| / (RTOL |ref| + ATOL): ≤ 1 means within tolerance."""
    warp_value = np.asarray(warp_value, dtype=np.float64)
    return float(np.max(np.abs(warp_value - ref_value) / (RTOL * np.abs(ref_value) + ATOL)))


@pytest.fixture(scope="module", params=range(len(MATERIALS)), ids=lambda i: f"material{i}")
def case(request):
    controls = MATERIALS[request.param]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # β = 0 warns of the roughness floor, tested elsewhere
        params = wh.HairParams(**controls)
    rng = np.random.default_rng(1000 + request.param)
    return controls, params, configurations(rng, PER_MATERIAL)


def test_eval(case):
    controls, params, (wo, wi, h, _) = case
    assert relative_excess(wh.bsdf.eval(params, wo, wi, h), ref.eval(controls, wo, wi, h)) <= 1.0


def test_eval_lobes(case):
    controls, params, (wo, wi, h, _) = case
    assert relative_excess(wh.bsdf.eval_lobes(params, wo, wi, h), ref.eval_lobes(controls, wo, wi, h)) <= 1.0


def test_attenuation(case):
    controls, params, (wo, _, h, _) = case
    assert relative_excess(wh.bsdf.attenuation(params, wo, h), ref.attenuation(controls, wo, h)) <= 1.0


def test_pdf(case):
    controls, params, (wo, wi, h, _) = case
    assert relative_excess(wh.bsdf.pdf(params, wo, wi, h), ref.pdf(controls, wo, wi, h)) <= 1.0


def test_sample(case):
    """The sampled direction matches the reference's; its pdf and weight match the reference's pdf and
    S/pdf at the returned direction.

    The pdf is compared at the direction the renderer will actually continue with (the float32 wi):
    near grazing, rounding wi to float32 moves θ by ulp(sin θ)/cos θ, which at β_m = 0 alone changes
    the density by ~1e-4 relative, so comparing with the density at the float64 direction would test
    float32 storage, not the model. Directions whose density underflows float32 (below 1e-30: the far
    tails of the narrowest lobes, reached only with a uniform of exactly 0) must come back with a density
    in that range too, and a weight that is either right or 0, never NaN.
    """
    controls, params, (wo, _, h, u) = case
    wi, weight, density = wh.bsdf.sample(params, wo, h, u)
    ref_wi, _, _ = ref.sample(controls, wo, h, u)
    assert np.max(np.linalg.norm(wi - ref_wi, axis=1)) <= RTOL

    ref_density = ref.pdf(controls, wo, wi, h)
    ref_weight = ref.eval(controls, wo, wi, h) / np.where(ref_density > 0.0, ref_density, 1.0)[:, None]
    underflow = ref_density < UNDERFLOW
    assert np.all(np.isfinite(weight)) and np.all(np.isfinite(density))
    assert np.all(density[underflow] < UNDERFLOW)
    close = np.abs(weight - ref_weight) <= RTOL * np.abs(ref_weight) + ATOL
    assert np.all(close[underflow] | (weight[underflow] == 0.0))
    assert relative_excess(density[~underflow], ref_density[~underflow]) <= 1.0
    assert relative_excess(weight[~underflow], ref_weight[~underflow]) <= 1.0
