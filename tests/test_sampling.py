"""The sampler draws from the density `pdf` reports, and that density is normalised."""

import numpy as np
import pytest
from helpers.sphere import from_angles, midpoint_grid
from scipy.stats import chi2

import warp_hair as wh

# (beta_m, beta_n, theta_o in degrees, h, colour): β_n ≥ 0.3 as in Mitsuba's test; several β_m, θ_o, h.
CHI2_CASES = [
    (0.1, 0.3, 30.0, 0.2, {"albedo": [0.8, 0.6, 0.4]}),
    (0.3, 0.3, -60.0, -0.9, {"albedo": [0.8, 0.6, 0.4]}),
    (0.3, 0.5, 0.0, 0.0, {"sigma_a": 0.0}),
    (0.5, 0.3, 45.0, 0.95, {"eumelanin": 1.3}),
    (0.7, 0.9, -20.0, -0.5, {"albedo": 0.9}),
    (0.2, 0.6, 75.0, 0.6, {"sigma_a": [0.1, 0.3, 0.9]}),
    (1.0, 0.4, 10.0, -0.3, {"albedo": [0.3, 0.2, 0.1]}),
    (0.15, 0.35, -80.0, 0.99, {"sigma_a": 0.0}),
    # A strong tilt: the sampler must rotate each lobe the way pdf does.
    (0.1, 0.4, 15.0, -0.2, {"albedo": [0.8, 0.6, 0.4], "alpha": 12.0}),
]
SIGNIFICANCE = 0.01
# Narrow lobes near the poles vary fastest in sin θ: more sub-cells along it.
N_Z, N_PHI, SUB_Z, SUB_PHI = 48, 96, 24, 4
N_SAMPLES = 1_000_000


def expected_counts(params, wo, h, n_samples):
    """n_samples × ∫_bin pdf dω for each (sin θ, φ) bin, by SUB_Z × SUB_PHI midpoint sub-cells per bin."""
    wi, d_omega = midpoint_grid(N_Z * SUB_Z, N_PHI * SUB_PHI)
    density = wh.bsdf.pdf(params, wo, wi, h).astype(np.float64).reshape(N_Z, SUB_Z, N_PHI, SUB_PHI)
    return density.sum(axis=(1, 3)) * d_omega * n_samples


def observed_counts(wi):
    iz = np.clip(((wi[:, 0] + 1.0) * 0.5 * N_Z).astype(int), 0, N_Z - 1)
    phi = np.arctan2(wi[:, 2], wi[:, 1])
    ip = np.clip(((phi + np.pi) / (2.0 * np.pi) * N_PHI).astype(int), 0, N_PHI - 1)
    return np.bincount(iz * N_PHI + ip, minlength=N_Z * N_PHI).reshape(N_Z, N_PHI).astype(np.float64)


def chi2_p_value(observed, expected):
    """Pearson's test, with bins expecting fewer than 5 samples pooled into one (as Mitsuba does)."""
    observed, expected = observed.ravel(), expected.ravel()
    small = expected < 5.0
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    if exp[-1] < 5.0:  # the pool itself too small: fold it into the smallest regular bin
        k = np.argmin(exp[:-1])
        obs[k] += obs[-1]
        exp[k] += exp[-1]
        obs, exp = obs[:-1], exp[:-1]
    stat = np.sum((obs - exp) ** 2 / exp)
    return chi2.sf(stat, len(exp) - 1)


@pytest.mark.parametrize("beta_m,beta_n,theta_o,h,colour", CHI2_CASES)
def test_chi2_sample_matches_pdf(beta_m, beta_n, theta_o, h, colour):
    rng = np.random.default_rng(2024)
    params = wh.HairParams(beta_m=beta_m, beta_n=beta_n, **colour)
    wo = from_angles(theta_o, 37.0)
    wi, _, _ = wh.bsdf.sample(params, wo, h, rng.random((N_SAMPLES, 3)))
    expected = expected_counts(params, wo, h, N_SAMPLES)
    # The sphere is covered by the bins, so the expected counts must account for every sample.
    assert abs(expected.sum() / N_SAMPLES - 1.0) < 2e-3
    # Šidák-corrected so that the whole family of cases rejects a correct sampler 1% of the time.
    threshold = 1.0 - (1.0 - SIGNIFICANCE) ** (1.0 / len(CHI2_CASES))
    assert chi2_p_value(observed_counts(wi), expected) > threshold


@pytest.mark.parametrize("beta_m", [0.1, 0.4, 1.0])
@pytest.mark.parametrize("beta_n", [0.1, 0.4, 1.0])
def test_pdf_integrates_to_one(beta_m, beta_n):
    """∫ pdf dω = 1 by midpoint quadrature on a fine equal-area grid, at several θ_o and h."""
    params = wh.HairParams(albedo=[0.7, 0.5, 0.3], beta_m=beta_m, beta_n=beta_n)
    wi, d_omega = midpoint_grid(2048, 768)
    for theta_o, h in [(-70.0, 0.9), (-10.0, -0.4), (40.0, 0.0), (85.0, -1.0)]:
        total = wh.bsdf.pdf(params, from_angles(theta_o, 120.0), wi, h).astype(np.float64).sum() * d_omega
        assert abs(total - 1.0) < 1e-3, (theta_o, h, total)
