"""Energy conservation and consistency of sampling (the reference implementations' own tests, tighter).

White furnace: a fiber with σ_a = 0 scatters everything, so ∫ S dω_i = 1 at every h (A_p sum to 1 and
every lobe is normalised); averaged over h it is the fiber's albedo of 1.
"""

import numpy as np
import pytest
from helpers.sphere import from_angles, random_directions, stratified_directions

import warp_hair as wh

GRID = [0.1, 0.3, 0.5, 0.7, 0.9]
BETAS = [(bm, bn) for bm in GRID for bn in GRID]


def uniform_estimate(params, wo, integrand, rng, n_h=16, n_z=256, n_phi=256):
    """∫∫ S(wo, wi, h) g(wi) dω_i dh/2 by uniform sampling: one jittered h in each of n_h strata, and for
    each a jittered direction in every equal-area cell of the sphere (a narrow lobe moves with h, so
    sharing h within a sweep of the sphere keeps the integrand smooth from cell to cell).
    """
    total = 0.0
    for k in range(n_h):
        wi = stratified_directions(rng, n_z, n_phi)
        h = -1.0 + 2.0 * (k + rng.random()) / n_h
        s = wh.bsdf.eval(params, wo, wi, h).astype(np.float64)
        total = total + (s * integrand(wi)[:, None]).mean(axis=0) * 4.0 * np.pi
    return total / n_h


def one(wi):
    return np.ones(len(wi))


@pytest.mark.parametrize("beta_m,beta_n", BETAS)
def test_white_furnace_uniform_sampling(beta_m, beta_n):
    """σ_a = 0, h uniform, wi uniform on the sphere: ∫ S dω within 2% of 1 (pbrt: 5%)."""
    rng = np.random.default_rng(int(100 * beta_m + 10 * beta_n))
    params = wh.HairParams(sigma_a=0.0, beta_m=beta_m, beta_n=beta_n)
    for theta_o in (-35.0, 70.0):
        wo = from_angles(theta_o, rng.uniform(-180.0, 180.0))
        albedo = uniform_estimate(params, wo, one, rng)
        assert np.all(np.abs(albedo - 1.0) < 0.02), (theta_o, albedo)


@pytest.mark.parametrize("beta_m,beta_n", BETAS)
def test_white_furnace_importance_sampling(beta_m, beta_n):
    """σ_a = 0: the importance-sampled estimate of ∫ S dω, mean of S(wi)/pdf(wi), within 0.5% of 1.

    S and pdf are evaluated by their own batch calls at the sampled directions, not taken from the
    sampler, so a pdf that disagreed with S's normalisation would show.
    """
    rng = np.random.default_rng(int(100 * beta_m + 10 * beta_n))
    params = wh.HairParams(sigma_a=0.0, beta_m=beta_m, beta_n=beta_n)
    n = 200_000
    wo = random_directions(rng, n)
    h = rng.uniform(-1.0, 1.0, n)
    wi, _, _ = wh.bsdf.sample(params, wo, h, rng.random((n, 3)))
    estimate = (wh.bsdf.eval(params, wo, wi, h) / wh.bsdf.pdf(params, wo, wi, h)[:, None]).mean(axis=0)
    assert np.all(np.abs(estimate - 1.0) < 0.005), estimate


@pytest.mark.parametrize("beta_n", [0.3, 0.5, 0.7, 0.9, 1.0])
@pytest.mark.parametrize("beta_m", [0.05, 0.3, 0.6, 1.0])
def test_every_sample_weight_is_one(beta_m, beta_n):
    """σ_a = 0: each weight S/pdf equals 1 within 1e-3 in every channel (pbrt, Mitsuba: 1e-3)."""
    rng = np.random.default_rng(7)
    params = wh.HairParams(sigma_a=0.0, beta_m=beta_m, beta_n=beta_n)
    n = 100_000
    wo = random_directions(rng, n)
    _, weight, density = wh.bsdf.sample(params, wo, rng.uniform(-1.0, 1.0, n), rng.random((n, 3)))
    assert np.all(density > 0.0)
    assert np.max(np.abs(weight - 1.0)) < 1e-3


def radiance_z2(wi):
    return wi[:, 2] ** 2


@pytest.mark.parametrize("beta_m,beta_n", [(0.2, 0.3), (0.3, 0.3), (0.5, 0.7), (0.8, 0.4), (0.4, 0.9)])
def test_sampling_consistency(beta_m, beta_n):
    """σ_a = 0.25 under L(w) = w.z²: importance-sampled and uniform estimates agree within 3%."""
    rng = np.random.default_rng(11)
    params = wh.HairParams(sigma_a=0.25, beta_m=beta_m, beta_n=beta_n)
    for theta_o in (-50.0, 10.0, 65.0):
        wo = from_angles(theta_o, rng.uniform(-180.0, 180.0))
        uniform = uniform_estimate(params, wo, radiance_z2, rng, n_h=128, n_z=96, n_phi=192)
        n = 1_000_000
        h = rng.uniform(-1.0, 1.0, n)
        wi, weight, _ = wh.bsdf.sample(params, wo, h, rng.random((n, 3)))
        importance = (weight * radiance_z2(wi)[:, None]).mean(axis=0)
        assert np.all(np.abs(importance / uniform - 1.0) < 0.03), (theta_o, importance, uniform)
