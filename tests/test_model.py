"""Properties of the model's parts: the residual lobe's series, the colour mappings, tilt and R-roughness."""

import numpy as np
import pytest
from helpers.sphere import direction, from_angles, midpoint_grid, random_directions

import warp_hair as wh
from warp_hair.model.params import EUMELANIN_SIGMA_A, PHEOMELANIN_SIGMA_A


def test_residual_lobe_is_the_series_sum():
    """A_3 = Σ_{p=3}^{60} A_p with A_p = A_{p−1} f T, f and T read back from A_0 = f and A_1 = (1 − f)² T."""
    rng = np.random.default_rng(3)
    n = 4096
    wo = random_directions(rng, n)
    h = rng.uniform(-0.95, 0.95, n)
    for colour in ({"albedo": [0.9, 0.5, 0.2]}, {"sigma_a": [0.05, 0.5, 3.0]}, {"eumelanin": 0.3}):
        A = wh.bsdf.attenuation(wh.HairParams(**colour), wo, h).astype(np.float64)
        f = A[:, 0, :1]
        T = A[:, 1] / (1.0 - f) ** 2
        ratio = f * T
        # Where fT < 0.75 the terms past p = 60 are below 1e-7 of the sum (grazing light on pale hair
        # needs more terms: that is why the model sums the series in closed form).
        kept = ratio[:, 0] < 0.75
        assert kept.mean() > 0.9
        series = sum(A[kept, 2] * ratio[kept] ** (p - 2) for p in range(3, 61))
        np.testing.assert_allclose(A[kept, 3], series, rtol=2e-5, atol=1e-9)


def test_attenuation_conserves_energy_without_absorption():
    rng = np.random.default_rng(4)
    n = 4096
    wo = random_directions(rng, n)
    wo[:4] = [[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 1, 0]]
    h = rng.uniform(-1.0, 1.0, n)
    h[:8] = [1, -1, 0, 1, -1, 1, 0, -1]
    A = wh.bsdf.attenuation(wh.HairParams(albedo=1.0), wo, h)
    np.testing.assert_allclose(A.sum(axis=1), 1.0, atol=2e-6)


def test_albedo_inversion():
    """σ_a falls as the albedo rises, reaches 0 at albedo 1, and depends on β_n as the talk's fit says."""
    albedos = np.linspace(0.05, 1.0, 40)
    for beta_n in (0.0, 0.3, 0.7, 1.0):
        with pytest.warns(UserWarning) if beta_n < 0.01 else _no_warning():
            sigma = np.array([wh.HairParams(albedo=a, beta_n=beta_n).absorption[0] for a in albedos])
        assert np.all(np.diff(sigma) < 0.0)
        assert sigma[-1] == 0.0
    # The β_n polynomial at β_n = 1 sums to 3.375: σ_a(albedo = e^-1) = 1 / 3.375².
    np.testing.assert_allclose(wh.HairParams(albedo=np.exp(-1.0), beta_n=1.0).absorption, 1.0 / 3.375**2, rtol=1e-12)
    # Rougher azimuthal scattering keeps light in the assembly longer: the same albedo needs more σ_a.
    assert wh.HairParams(albedo=0.5, beta_n=0.8).absorption[0] > wh.HairParams(albedo=0.5, beta_n=0.2).absorption[0]


class _no_warning:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_melanin_coefficients():
    np.testing.assert_allclose(wh.HairParams(eumelanin=1.0).absorption, [0.419, 0.697, 1.37])
    np.testing.assert_allclose(wh.HairParams(pheomelanin=1.0).absorption, [0.187, 0.4, 1.05])
    np.testing.assert_allclose(
        wh.HairParams(eumelanin=0.3, pheomelanin=0.1).absorption, 0.3 * EUMELANIN_SIGMA_A + 0.1 * PHEOMELANIN_SIGMA_A
    )
    # The benchmark scene's σ_a is eumelanin 0.3 + pheomelanin 0.1, rounded to 4 digits.
    np.testing.assert_allclose(
        wh.HairParams(eumelanin=0.3, pheomelanin=0.1).absorption, [0.1444, 0.2491, 0.516], atol=1e-4
    )


def lobe_peak_theta(params, lobe, theta_o_deg, dphi):
    """θ_i (degrees) where the lobe's value peaks along the meridian Δφ = dphi, at h = 0."""
    theta_i = np.linspace(-89.0, 89.0, 35601)
    phi_o = np.radians(90.0)
    wo = from_angles(theta_o_deg, 90.0)
    wi = direction(np.sin(np.radians(theta_i)), np.full_like(theta_i, phi_o + dphi))
    values = wh.bsdf.eval_lobes(params, wo, wi, 0.0)[:, lobe, 0]
    return theta_i[np.argmax(values)]


def scale_normal(alpha_deg):
    """The outward normal of a cuticle scale at h = 0, in the fiber's local frame (x from root to tip, z the
    cylinder's normal): the scales overlap like roof tiles with their free edges toward the tip, so their
    normals lean toward the root (−x) by α."""
    a = np.radians(alpha_deg)
    return np.array([-np.sin(a), 0.0, np.cos(a)])


def mirror_theta(wo, normal):
    """θ (degrees) of wo's mirror reflection off a surface with that normal."""
    reflected = 2.0 * (wo @ normal) * normal - wo
    return np.degrees(np.arcsin(reflected[0]))


@pytest.mark.parametrize("theta_o", [-30.0, 0.0, 25.0])
def test_tilt_moves_r_to_the_scales_mirror_and_tt_trt_toward_the_tip(theta_o):
    """R peaks where a mirror reflection off the tilted scale sends wo (toward the root, by 2α); TT and TRT move
    the other way, toward the tip, by α and 4α (d'Eon et al. 2011's magnitudes). At h = 0 the lobes' azimuthal
    centres are Δφ = 0, π and 2π ≡ 0. The shifts are measured against the untilted fiber, which cancels the
    small offset of M's peak from the mirror angle."""
    alpha = 3.0
    # Narrow lobes: at β_m = 0.05 the drift of M's peak with θ_o stays below 0.05° for the TRT lobe's 4v.
    tilted = wh.HairParams(albedo=0.8, beta_m=0.05, beta_n=0.3, alpha=alpha)
    straight = tilted.replace(alpha=0.0)
    wo = from_angles(theta_o, 90.0)

    def moved(lobe, dphi):
        return lobe_peak_theta(tilted, lobe, theta_o, dphi) - lobe_peak_theta(straight, lobe, theta_o, dphi)

    geometric_r = mirror_theta(wo, scale_normal(alpha)) - mirror_theta(wo, scale_normal(0.0))
    assert geometric_r < 0.0  # toward the root
    assert abs(moved(0, 0.0) - geometric_r) < 0.1
    assert abs(moved(1, np.pi) - alpha) < 0.1
    assert abs(moved(2, 0.0) - 4.0 * alpha) < 0.1


def test_tilt_sampling_follows_the_scales_mirror():
    """A black fiber (σ_a = 50) leaves only R, so the sampler's directions cluster about the mirror reflection
    off the tilted scale: on the root side of the untilted mirror direction, by 2α."""
    rng = np.random.default_rng(7)
    alpha = 5.0
    params = wh.HairParams(sigma_a=50.0, beta_m=0.05, beta_n=0.3, alpha=alpha)
    wo = from_angles(20.0, 90.0)
    wi, _, _ = wh.bsdf.sample(params, wo, 0.0, rng.random((200_000, 3)))
    theta_i = np.degrees(np.arcsin(np.clip(wi[:, 0], -1.0, 1.0)))
    expected = mirror_theta(wo, scale_normal(alpha))
    assert abs(np.median(theta_i) - expected) < 0.3, (np.median(theta_i), expected)


def test_r_roughness_scale_changes_the_r_lobe_only():
    rng = np.random.default_rng(5)
    n = 20_000
    wo, wi = random_directions(rng, n), random_directions(rng, n)
    h = rng.uniform(-1.0, 1.0, n)
    base = wh.HairParams(albedo=[0.7, 0.5, 0.3], beta_m=0.2, beta_n=0.4)
    fur = base.replace(r_roughness_scale=3.0)
    lobes_base = wh.bsdf.eval_lobes(base, wo, wi, h)
    lobes_fur = wh.bsdf.eval_lobes(fur, wo, wi, h)
    np.testing.assert_array_equal(lobes_base[:, 1:], lobes_fur[:, 1:])
    assert np.max(np.abs(lobes_base[:, 0] - lobes_fur[:, 0])) > 1e-2

    # Same energy (A_0), spread wider: lower peak, same integral over the sphere.
    grid, d_omega = midpoint_grid(1024, 1024)
    wo1 = from_angles(20.0, 90.0)
    r_base = wh.bsdf.eval_lobes(base, wo1, grid, 0.3)[:, 0, 0].astype(np.float64)
    r_fur = wh.bsdf.eval_lobes(fur, wo1, grid, 0.3)[:, 0, 0].astype(np.float64)
    np.testing.assert_allclose(r_fur.sum() * d_omega, r_base.sum() * d_omega, rtol=2e-3)
    assert r_fur.max() < 0.7 * r_base.max()
