"""Render-level gradients (warp_hair.renderer.gradients) against finite differences of `render`.

The scene is a sparse single layer of fibers (24 strands over a 16×16 view) under a directional light and a
constant sky, max_depth 8 without roulette. Sparse on purpose: a central difference of `render` with common
random numbers is noisy wherever a change of θ flips a discrete choice of a path (its lobe, which fiber a ray
hits), with a variance ∝ 1/ε; a dense assembly makes most paths long and the difference useless at any affordable
spp (measured: 40% relative standard error for the albedo at 4×256 spp with 3 layers of 40 fibers, 1% here).
Both estimators are run with several independent seeds and compared through the standard error of the
difference of their means. One test compares them without common random numbers, with high-spp differences.
"""

import numpy as np
import pytest
from helpers.scenes import SPARSE_HAIR, sparse_scene

from warp_hair.controls import SCALAR_CONTROLS
from warp_hair.renderer.gradients import render_grad
from warp_hair.renderer.render import render

HAIR = SPARSE_HAIR
# Central-difference steps (ε; the differences are extrapolated from ε and ε/2): large enough that the 1/ε
# variance of the discontinuities stays small.
STEPS = {"albedo": 0.04, "beta_m": 0.04, "beta_n": 0.08, "alpha": 1.0, "eta": 0.04, "r_roughness_scale": 0.4}
# 32 seeds: beside the directional light the sky is never light-sampled (renderer/light_sampler.py), so its light
# arrives through BSDF samples whose lobe choices a change of the albedo flips; with 8 the red albedo's difference
# resolved its gradient to 65% only (3 standard errors).
SEEDS = range(1, 33)


def loss(scene, adjoint, seed):
    return float((adjoint * render(scene, seed=seed)).sum())


def mean_and_se(samples):
    samples = np.asarray(samples, dtype=np.float64)
    return samples.mean(axis=0), samples.std(axis=0, ddof=1) / np.sqrt(len(samples))


@pytest.fixture(scope="module")
def fd_case():
    scene = sparse_scene(HAIR)
    adjoint = np.random.default_rng(0).normal(size=(16, 16, 3)) + 0.5
    grads = [render_grad(scene, adjoint, seed=s) for s in SEEDS]
    return scene, adjoint, grads


def central_difference(scene, adjoint, name, component=None):
    """Per seed, the Richardson extrapolation (4 D(ε/2) − D(ε)) / 3 of central differences D: its error is
    O(ε⁴). Plain D(ε) is biased by ε²/6 times the third derivative, which is not small for the roughnesses:
    for β_m = 0.3 (this scene, 24 seeds) D = −11.0, −8.7, +1.4 at ε = 0.02, 0.04, 0.08, against a gradient of
    −12.8 ± 0.7."""
    d_full = _central_difference(scene, adjoint, name, component, STEPS[name])
    d_half = _central_difference(scene, adjoint, name, component, 0.5 * STEPS[name])
    return [(4.0 * h - f) / 3.0 for f, h in zip(d_full, d_half)]


def _central_difference(scene, adjoint, name, component, step):
    value = np.array(scene.hair.to_dict()[name], dtype=np.float64)
    out = []
    for s in SEEDS:
        plus, minus = value.copy(), value.copy()
        if component is None:
            plus, minus = float(plus + step), float(minus - step)
        else:
            plus[component] += step
            minus[component] -= step
            plus, minus = list(plus), list(minus)
        up = scene_from_dict_like(scene, scene.hair.replace(**{name: plus}))
        down = scene_from_dict_like(scene, scene.hair.replace(**{name: minus}))
        out.append((loss(up, adjoint, s) - loss(down, adjoint, s)) / (2.0 * step))
    return out


def scene_from_dict_like(scene, hair):
    import copy

    other = copy.copy(scene)
    other.hair = hair
    return other


@pytest.mark.parametrize(
    "name, component",
    [
        ("albedo", 0),
        ("albedo", 1),
        ("albedo", 2),
        ("beta_m", None),
        ("beta_n", None),
        ("alpha", None),
        ("eta", None),
        ("r_roughness_scale", None),
    ],
)
def test_gradient_matches_finite_differences(fd_case, name, component):
    """Every control (albedo input, so ∂/∂β_n includes the albedo inversion) within max(3%, 3 standard errors)."""
    scene, adjoint, grads = fd_case
    g = [np.asarray(x[name])[component] if component is not None else x[name] for x in grads]
    g_mean, g_se = mean_and_se(g)
    fd_mean, fd_se = mean_and_se(central_difference(scene, adjoint, name, component))
    se = np.hypot(g_se, fd_se)
    assert abs(g_mean - fd_mean) <= max(0.03 * abs(fd_mean), 3.0 * se), (g_mean, fd_mean, g_se, fd_se)
    # Meaningful: the comparison resolves the gradient to better than 40% of its size (measured: 3 SE = 17% of it
    # for the red albedo, 15% r_roughness_scale, 14% β_n, 12% α, 4–9% the rest).
    assert 3.0 * se < 0.4 * abs(fd_mean), (g_mean, fd_mean, g_se, fd_se)


# Unbiasedness without common random numbers: (control, direction in it or None for a scalar, five-point step h,
# number of difference samples). The albedo is moved along grey (1, 1, 1): one directional derivative exercises
# all three channels. The steps keep the stencil's O(h⁴) error small against the noise (from the central
# differences with common random numbers quoted in `central_difference`: for β_m the stencil gives −12.1 at
# h = 0.04 and −11.8 at h = 0.02, against a gradient of −12.8 ± 0.7). β_m, the noisiest relative to its gradient
# on both sides, gets twice the samples.
UNBIASED_STEPS = (("albedo", np.ones(3), 0.04, 12), ("beta_m", None, 0.04, 24), ("beta_n", None, 0.08, 12))
UNBIASED_GRADIENT_SEEDS = range(10_000, 10_048)  # 256 spp each
UNBIASED_FD_SPP = 512


def test_gradient_is_unbiased_without_common_random_numbers():
    """The mean of render_grad over independent seeds equals the derivative of the expected loss, estimated by
    five-point differences (h, 2h) of renders that share no seed with each other or with the gradient passes:
    within 3.5 standard errors of the difference of the means. With common random numbers (the test above) a
    bias correlated with the seed's paths would cancel; here nothing is shared.

    The difference estimate (8(L(h) − L(−h)) − (L(2h) − L(−2h)))/12h of independent renders has variance
    ≈ 0.9 σ_L²/h², so the standard error of the mean depends on the total spp only: the samples are many and
    small (512 spp), for a better estimate of that error. Measured (gradient vs difference): albedo 23.98 ± 0.03
    vs 24.7 ± 1.1, β_m −12.7 ± 0.5 vs −11.8 ± 1.0, β_n −24.4 ± 0.5 vs −24.3 ± 0.6; 3.5 combined standard errors
    are 16%, 34% and 11% of the gradient, where the second assertion's bound is 50%.
    """
    scene = sparse_scene(HAIR)
    adjoint = np.random.default_rng(0).normal(size=(16, 16, 3)) + 0.5
    grads = [render_grad(scene, adjoint, spp=256, seed=s) for s in UNBIASED_GRADIENT_SEEDS]
    for index, (name, direction, h, samples) in enumerate(UNBIASED_STEPS):
        if direction is None:
            g = [x[name] for x in grads]
        else:
            g = [float(np.dot(x[name], direction)) for x in grads]
        base = np.array(scene.hair.to_dict()[name], dtype=np.float64)
        differences = []
        for sample in range(samples):
            losses = {}
            for j, k in enumerate((-2, -1, 1, 2)):
                value = base + k * h * (1.0 if direction is None else direction)
                moved = scene_from_dict_like(scene, scene.hair.replace(**{name: value.tolist()}))
                seed = 20_000 + 1_000 * index + 4 * sample + j
                losses[k] = float((adjoint * render(moved, spp=UNBIASED_FD_SPP, seed=seed)).sum())
            differences.append((8.0 * (losses[1] - losses[-1]) - (losses[2] - losses[-2])) / (12.0 * h))
        g_mean, g_se = mean_and_se(g)
        fd_mean, fd_se = mean_and_se(differences)
        se = np.hypot(g_se, fd_se)
        assert abs(g_mean - fd_mean) < 3.5 * se, (name, g_mean, g_se, fd_mean, fd_se)
        assert 3.5 * se < 0.5 * abs(fd_mean), (name, g_mean, g_se, fd_mean, fd_se)


def test_gradient_of_a_matching_target_vanishes():
    """∂/∂θ of 0.5‖image − target‖² at the target's own controls is 0 up to noise; at other controls it is not.

    The primal image of the adjoint is rendered with a different seed from the gradient pass (else their noise
    correlates and the product is biased), and the target with a third.
    """
    scene = sparse_scene(HAIR)
    spp = 32
    samples, off = [], []
    other = scene_from_dict_like(scene, scene.hair.replace(albedo=[0.5, 0.35, 0.2]))
    for k in range(6):
        target = render(scene, spp=spp, seed=100 + k)
        adjoint = render(scene, spp=spp, seed=200 + k) - target
        samples.append(_vector(render_grad(scene, adjoint, spp=spp, seed=300 + k)))
        adjoint = render(other, spp=spp, seed=200 + k) - target
        off.append(_vector(render_grad(other, adjoint, spp=spp, seed=300 + k)))
    mean, se = mean_and_se(samples)
    assert np.all(np.abs(mean) <= 4.0 * se + 1e-6), (mean, se)
    off_mean, off_se = mean_and_se(off)
    # A darker albedo than the target's: the loss falls as the albedo rises toward it.
    assert np.all(off_mean[:3] < -4.0 * off_se[:3]), (off_mean, off_se)


def _vector(g):
    return np.concatenate([np.atleast_1d(np.asarray(g[k], dtype=np.float64)) for k in g])


def test_paths_are_the_renders():
    """The gradient pass traces render's paths: with the same seed its image is render's, bit for bit on the CPU
    (the closed-form Jacobian comes from the same evaluation of the lobes as the value that steers the path)."""
    scene = sparse_scene(HAIR)
    image = render(scene, spp=16, seed=5)
    _, traced = render_grad(scene, np.ones_like(image), spp=16, seed=5, return_image=True)
    np.testing.assert_array_equal(traced, image)


def test_adjoint_is_checked():
    scene = sparse_scene(HAIR, resolution=(4, 3))
    with pytest.raises(ValueError, match="shape"):
        render_grad(scene, np.zeros((4, 3, 3)), spp=1)
    bad = np.zeros((3, 4, 3))
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        render_grad(scene, bad, spp=1)


def test_threads_do_not_change_the_gradient():
    scene = sparse_scene(HAIR, resolution=(8, 8))
    adjoint = np.random.default_rng(1).normal(size=(8, 8, 3))
    one = _vector(render_grad(scene, adjoint, spp=4, threads=1))
    np.testing.assert_array_equal(one, _vector(render_grad(scene, adjoint, spp=4, threads=2)))


def test_melanin_and_sigma_a_names():
    scene = sparse_scene({"eumelanin": 0.5, "pheomelanin": 0.2}, resolution=(4, 4))
    g = render_grad(scene, np.ones((4, 4, 3)), spp=2)
    assert set(g) == {"eumelanin", "pheomelanin", *SCALAR_CONTROLS}
    assert g["eumelanin"] < 0.0  # more melanin, darker
    scene = sparse_scene({"sigma_a": [0.2, 0.3, 0.4]}, resolution=(4, 4))
    g = render_grad(scene, np.ones((4, 4, 3)), spp=2)
    assert np.shape(g["sigma_a"]) == (3,) and np.all(np.asarray(g["sigma_a"]) < 0.0)
