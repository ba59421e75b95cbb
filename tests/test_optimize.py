"""The optimize package's parts: latents, losses, target directories and their errors, the fit command's checks."""

import dataclasses
import json
import math
import shutil
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.scenes import front_camera, toml_text

from optimize.cli import main
from optimize.fit import Batches, FitSettings, check_settings, spp_at
from optimize.latents import SPECS, parse_control_names
from optimize.linearize import Linearization, linearize
from optimize.losses import image_loss, loss_scale
from optimize.refine import drifting, inside, mean_covariance
from optimize.target import SHIPPED_TARGETS, load_target, make_target, shipped_targets
from optimize.uncertainty import estimate_uncertainty
from warp_hair.io import read_exr, write_exr
from warp_hair.model.params import TALK_ALBEDO_INVERSION
from warp_hair.renderer.render import render
from warp_hair.torch import default_grad_seed, scene_with_controls


def scene_text(w, h, dz, red):
    """A 30-fiber draped swatch lit from the front (dz < 0) or from behind, w×h pixels."""
    return toml_text(
        {
            "camera": front_camera(0.2, (w, h)),
            "lights": [{"type": "directional", "direction": [0.2, -0.3, dz], "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {
                "generator": "swatch",
                "count": 30,
                "layers": 2,
                "length": 0.3,
                "width": 0.2,
                "radius": 0.004,
                "drape": 0.2,
                "segments": 12,
                "seed": 5,
            },
            "hair": {"albedo": [red, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.4},
            "render": {"spp": 4, "max_depth": 8},
        }
    )


def write_target(directory, w=8, h=6, red=0.6, image_shape=None, extra="", back_red=None):
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "scene_front.toml").write_text(scene_text(w, h, -1.0, red))
    (directory / "scene_back.toml").write_text(scene_text(w, h, 1.0, red if back_red is None else back_red))
    (directory / "target.toml").write_text(
        '[[images]]\nscene = "scene_front.toml"\nimage = "front.exr"\n'
        + extra
        + '\n[[images]]\nscene = "scene_back.toml"\nimage = "back.exr"\n'
    )
    shape = image_shape or (h, w, 3)
    for name in ("front", "back"):
        write_exr(directory / f"{name}.exr", np.full(shape, 0.25, dtype=np.float32))
    return directory


# ---------------------------------------------------------------------------------------------------------------
# Latents


@pytest.mark.parametrize("name", [n for n in SPECS if n != "albedo"])
def test_latent_round_trip_stays_inside_the_interval(name):
    spec = SPECS[name]
    hi = spec.hi if math.isfinite(spec.hi) else spec.lo + 10.0
    values = torch.linspace(spec.lo, hi, 9, dtype=torch.float64)[1:-1]
    back = spec.from_latent(spec.to_latent(values, None), None)
    assert torch.allclose(back, values, rtol=1e-10, atol=1e-12)
    extreme = spec.from_latent(torch.tensor([-30.0, 30.0], dtype=torch.float64), None)
    assert (extreme >= spec.lo).all() and (extreme <= spec.hi).all()


@pytest.mark.parametrize("inversion", [TALK_ALBEDO_INVERSION, (4.0, 3.0, -6.0, 2.0, 1.0, -0.5)])
def test_albedo_latent_is_log_sigma_a_of_the_inversion(inversion):
    """With the talk's coefficients and with custom ones: the latent follows the material's own inversion."""
    from warp_hair.model.params import sigma_a_from_albedo

    albedo = torch.tensor([0.05, 0.5, 0.95], dtype=torch.float64)
    for beta_n in (0.01, 0.3, 0.9):
        z = SPECS["albedo"].to_latent(albedo, torch.tensor(beta_n, dtype=torch.float64), inversion)
        expected = sigma_a_from_albedo(albedo.numpy(), beta_n, inversion)
        assert np.allclose(torch.exp(z).numpy(), expected, rtol=1e-12)
        assert torch.allclose(SPECS["albedo"].from_latent(z, beta_n, inversion), albedo, rtol=1e-12)


def test_start_on_a_bound_is_refused():
    with pytest.raises(ValueError, match=r"beta_m = 0.005 cannot start a fit: it must lie strictly inside \(0.01, 1\)"):
        SPECS["beta_m"].check_start([0.005], "init")
    with pytest.raises(ValueError, match=r"albedo\[2\] = 1.0"):
        SPECS["albedo"].check_start([0.5, 0.5, 1.0], "init")


def test_control_names_are_checked():
    assert parse_control_names("albedo, beta_m", "albedo") == ("albedo", "beta_m")
    with pytest.raises(ValueError, match="unknown control 'beta'"):
        parse_control_names("albedo,beta", "albedo")
    with pytest.raises(ValueError, match="colour as 'albedo'"):
        parse_control_names(["sigma_a"], "albedo")
    with pytest.raises(ValueError, match="listed twice"):
        parse_control_names(["beta_m", "beta_m"], "albedo")


def test_spp_schedule_grows_to_the_final_spp():
    schedule = [spp_at(i, 100, 8) for i in range(100)]
    assert schedule[0] == 2 and schedule[30] == 4 and schedule[-1] == 8
    assert schedule == sorted(schedule)


# ---------------------------------------------------------------------------------------------------------------
# Losses


def test_losses_against_their_formulas():
    gen = torch.Generator().manual_seed(0)
    a, b = torch.rand(12, 10, 3, generator=gen), torch.rand(12, 10, 3, generator=gen)
    mask = torch.rand(12, 10, generator=gen) > 0.3
    assert torch.isclose(image_loss(a, b), ((a - b) ** 2).mean() / (b**2).mean())
    assert torch.isclose(image_loss(a, b, "l1", mask), (a - b)[mask].abs().mean() / b[mask].mean())
    scale = b + 0.01 * b.mean()
    assert torch.isclose(image_loss(a, b, "rel_l2"), (((a - b) / scale) ** 2).mean())
    blocks = lambda x: x[:8, :10].reshape(4, 2, 5, 2, 3).mean(dim=(1, 3))  # noqa: E731
    assert torch.isclose(
        image_loss(a[:8, :10], b[:8, :10], pool=2), ((blocks(a) - blocks(b)) ** 2).mean() / (blocks(b) ** 2).mean()
    )


def test_pooled_loss_averages_blocks_and_skips_masked_pixels():
    a = torch.ones(4, 4, 3)
    b = torch.ones(4, 4, 3)
    a[0, 0] = 5.0  # one bright pixel in the top-left 2×2 block: the block mean is 2, one more than the target's
    assert torch.isclose(image_loss(a, b, pool=2), torch.tensor(1.0 / 4))
    mask = torch.ones(4, 4, dtype=torch.bool)
    mask[0, 0] = False  # masked out: nothing differs any more
    assert image_loss(a, b, pool=2, mask=mask) == 0
    mask[:2, :2] = False  # a block with no counted pixel is left out, not counted as 0/0
    assert torch.isfinite(image_loss(a, b, pool=2, mask=mask))


# ---------------------------------------------------------------------------------------------------------------
# Target directories


def test_target_loads_with_truth_and_mask(tmp_path):
    directory = write_target(tmp_path / "t", extra='mask = "mask.png"\n')
    from PIL import Image

    mask = np.zeros((6, 8), dtype=np.uint8)
    mask[2:, 3:] = 255
    Image.fromarray(mask).save(directory / "mask.png")
    (directory / "truth.json").write_text(json.dumps({"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.4}))
    target = load_target(directory)
    assert [im.name for im in target.images] == ["front", "back"]
    assert target.images[0].mask.sum() == 4 * 5 and target.images[1].mask is None
    assert target.truth.beta_n == 0.4


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: (d / "target.toml").unlink(), "target.toml: not found"),
        (lambda d: (d / "front.exr").unlink(), "front.exr: target image not found"),
        (
            lambda d: write_exr(d / "front.exr", np.zeros((5, 8, 3), np.float32)),
            r"8x5 pixels but scene_front.toml's camera renders 8x6",
        ),
        (
            lambda d: write_exr(
                d / "back.exr",
                np.where(np.arange(48).reshape(6, 8, 1) == 13, np.nan, 0.1).repeat(3, 2).astype(np.float32),
            ),
            r"back.exr: 3 NaN or infinite value\(s\), the first at pixel \(x=5, y=1\)",
        ),
        (lambda d: write_exr(d / "back.exr", -np.ones((6, 8, 3), np.float32)), "negative radiance"),
        (
            lambda d: (d / "target.toml").write_text('[[images]]\nscene = "scene_front.toml"\n'),
            r'needs image = "<file name>"',
        ),
        (
            lambda d: (d / "target.toml").write_text(
                '[[images]]\nscene = "scene_front.toml"\nimage = "front.exr"\nweight = 2\n'
            ),
            r"unknown key\(s\) \['weight'\]",
        ),
        (lambda d: (d / "truth.json").write_text('{"albedo": 0.5, "beta": 0.3}'), r"unknown key\(s\) \['beta'\]"),
    ],
)
def test_bad_targets_are_named(tmp_path, change, message):
    directory = write_target(tmp_path / "t")
    change(directory)
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        load_target(directory)


def test_images_of_one_target_must_share_the_hair(tmp_path):
    with pytest.raises(ValueError, match="different \\[hair\\] tables"):
        load_target(write_target(tmp_path / "t", back_red=0.7))


def test_fit_settings_are_checked(tmp_path):
    target = load_target(write_target(tmp_path / "t"))
    with pytest.raises(ValueError, match="unknown loss 'l3'"):
        check_settings(target, FitSettings(loss="l3"))
    with pytest.raises(ValueError, match=r"init gives control\(s\) \['eta'\] that are not fitted"):
        check_settings(target, FitSettings(init={"eta": 1.5}))
    with pytest.raises(ValueError, match="spp must be an integer >= 1"):
        check_settings(target, FitSettings(spp=0))
    with pytest.raises(ValueError, match="Gauss–Newton steps need a sum-of-squares loss"):
        check_settings(target, FitSettings(loss="l1", refine=2))
    with pytest.raises(ValueError, match="refine must be an integer >= 0"):
        check_settings(target, FitSettings(refine=-1))


def test_linearisation_reproduces_the_loss_and_its_gradient_crosses_the_passes():
    """The linearised loss is the fit's image loss of its two renders, and its gradient meets each render's
    residual with the other render's Jacobian (the two passes' products differ, so a product within one pass
    would show)."""
    target = load_target(Path(__file__).resolve().parent.parent / "targets" / "black_straight")
    truth = {name: target.truth.to_dict()[name] for name in ("albedo", "beta_m", "beta_n")}
    for loss in ("l2", "rel_l2"):
        settings = FitSettings(loss=loss)
        lin = linearize(target, truth, settings, spp=2, seed=3)
        losses = []
        for k, image in enumerate(target.images):
            scene = scene_with_controls(image.scene, truth)
            for seed in (3 + k, default_grad_seed(3 + k)):
                losses.append(
                    float(
                        image_loss(
                            torch.from_numpy(render(scene, spp=2, seed=seed)),
                            torch.from_numpy(image.image),
                            loss,
                            None,
                            settings.pool,
                        )
                    )
                )
        assert lin.loss == pytest.approx(np.mean(losses), rel=1e-5)
        (r1, r2), (a1, a2), w = lin.residuals, lin.jacobians, lin.loss_weights
        assert w.sum() == pytest.approx(1.0)
        np.testing.assert_allclose(lin.gradient, 0.5 * (a1.T @ (w * r2) + a2.T @ (w * r1)))
        assert not np.allclose(a1.T @ (w * r1), a1.T @ (w * r2), rtol=1e-2)


def _noisy_linearization(rng, jacobian, offset, noise, jacobian_noise, channel_correlation=0.0):
    """Two passes of a linear model r = J·offset + noise whose Jacobian is estimated with noise, as a render's is;
    residuals come three to a pixel, their noise correlated within it as `channel_correlation` says."""
    n = jacobian.shape[0]
    shared = np.repeat(rng.standard_normal((2, n // 3)), 3, axis=1)
    own = rng.standard_normal((2, n))
    rho = channel_correlation
    residuals = jacobian @ offset + noise * (np.sqrt(1 - rho) * own + np.sqrt(rho) * shared)
    jacobians = jacobian + jacobian_noise * rng.standard_normal((2, *jacobian.shape))
    return Linearization(
        values={},
        residuals=residuals,
        variances=np.full((2, n), noise**2),
        jacobians=jacobians,
        images=[],
        loss_weights=np.full(n, 1.0 / n),
    )


def test_curvature_is_unbiased_where_the_jacobian_is_mostly_noise():
    """A column whose per-residual noise is 3x its signal (fur_patch's β_n): the product of a pass's Jacobian with
    itself is inflated about 10-fold on that diagonal, the crossed product of independent passes is not."""
    rng = np.random.default_rng(5)
    n = 19998
    jacobian = np.stack([np.full(n, 1.0), rng.choice([-0.1, 0.1], n) + 0.05], axis=1)
    lin = _noisy_linearization(rng, jacobian, np.zeros(2), 0.01, np.array([0.05, 0.3]))
    exact = jacobian.T @ jacobian / n
    one_pass = lin.jacobians[0].T @ lin.jacobians[0] / n
    assert one_pass[1, 1] > 5 * exact[1, 1]
    np.testing.assert_allclose(lin.curvature, exact, rtol=0.15, atol=2e-3)


def test_curvature_directions_standard_errors_match_their_scatter():
    """The jackknife standard error of each crossed-curvature direction's value (`curvature_directions`) is the
    scatter of that value over independent sets of Jacobians for a well-determined column, and no smaller than it
    (up to 1.6x larger: the jackknife of a nearly degenerate U-statistic errs high) for a noise-dominated one, so
    that a direction is never judged determined on an error too small."""
    from optimize.linearize import curvature_directions

    rng = np.random.default_rng(21)
    n, count = 600, 16
    jacobian = np.stack([rng.standard_normal(n), 0.05 * rng.standard_normal(n)], axis=1)
    weights = np.full(n, 1.0 / n)
    values, errors = [], []
    for _ in range(200):
        jacobians = jacobian + np.array([0.1, 0.5]) * rng.standard_normal((count, n, 2))
        v, vectors, e = curvature_directions(jacobians, weights)
        order = np.argsort(np.abs(vectors[1]))  # [the first column's direction, the second's]
        values.append(v[order])
        errors.append(e[order])
    ratio = np.mean(errors, axis=0) / np.std(values, axis=0)
    assert ratio[0] == pytest.approx(1.0, rel=0.15) and 0.9 < ratio[1] < 1.6
    exact = np.diag(jacobian.T @ jacobian / n)
    np.testing.assert_allclose(np.mean(values, axis=0), exact, rtol=0.1, atol=3 * np.std(values, axis=0)[1] / 14)


def test_a_direction_the_jacobians_do_not_determine_takes_the_range_not_the_noise():
    """β_n's column all noise and no signal (blender_thick's, averaged over the layers' places): the product
    fallback counts that noise as curvature and gives β_n a σ a fraction of its range; `pinned` finds the direction
    (its crossed value within its error of zero) and σ along it is the range's (the root mean square distance from
    the estimate to any β_n in it), with a warning that names it. A determined column is left as it was, the
    linearisation unchanged."""
    from optimize.uncertainty import pinned

    rng = np.random.default_rng(22)
    n = 3999
    jacobian = np.stack([rng.standard_normal(n), np.zeros(n)], axis=1)
    lin = _noisy_linearization(rng, jacobian, np.zeros(2), 0.2, np.array([0.02, 1.0]))
    lin = dataclasses.replace(lin, values={"beta_m": 0.3, "beta_n": 0.4}, scatter=0.002)
    lin = dataclasses.replace(lin, earlier_jacobians=jacobian + np.array([0.02, 1.0]) * rng.standard_normal((8, n, 2)))
    naive = estimate_uncertainty(lin).uncertainties["beta_n"]
    determined, unpinned = pinned(lin)
    assert unpinned is not None and unpinned.vectors.shape == (2, 1) and abs(unpinned.vectors[1, 0]) > 0.99
    result = estimate_uncertainty(determined, unpinned=unpinned)
    # β_n = 0.4 in (0.01, 1): the root mean square distance from 0.4 to a β_n uniform over the range.
    low, high = SPECS["beta_n"].lo - 0.4, SPECS["beta_n"].hi - 0.4
    width = math.sqrt((high**3 - low**3) / (3 * (high - low)))
    assert naive < 0.2 * width
    assert result.uncertainties["beta_n"] == pytest.approx(width, rel=1e-3)
    assert result.parts["range"]["beta_n"] == pytest.approx(width, rel=1e-3)
    assert result.uncertainties["beta_m"] == pytest.approx(estimate_uncertainty(lin).uncertainties["beta_m"], rel=0.05)
    assert any("do not determine" in w and "beta_n" in w and "--fix" in w for w in result.warnings)
    signal = dataclasses.replace(lin, jacobians=lin.jacobians + np.array([0.0, 1.0]), curvature=None)
    signal = dataclasses.replace(signal, earlier_jacobians=signal.earlier_jacobians + np.array([0.0, 1.0]))
    kept, none = pinned(signal)
    assert none is None and kept is signal


def test_the_range_along_a_free_direction_is_the_chord_through_the_estimate():
    """σ² along a free direction is the mean square distance from the estimate to a point anywhere on the chord of
    the ranges through it: width²/12 at a range's middle, width²/3 at its end; a control without an upper end
    (exposure) bounds the chord only where it reaches an end, and only a chord without ends is infinite."""
    from optimize.uncertainty import Unpinned, range_covariance

    def sigma(values, direction):
        v = np.array(direction, dtype=float)[:, None] / np.linalg.norm(direction)
        return np.sqrt(np.diag(range_covariance(values, Unpinned(v, np.zeros(1), np.ones(1)))))

    lo, hi = SPECS["beta_n"].lo, SPECS["beta_n"].hi
    middle = 0.5 * (lo + hi)
    np.testing.assert_allclose(sigma({"beta_m": 0.3, "beta_n": middle}, [0, 1]), [0, (hi - lo) / math.sqrt(12)])
    np.testing.assert_allclose(sigma({"beta_m": 0.3, "beta_n": hi - 1e-12}, [0, 1]), [0, (hi - lo) / math.sqrt(3)])
    # Mostly β_n, a little exposure: β_n's ends bound the chord; exposure moves by its share of it.
    mixed = sigma({"beta_n": middle, "exposure": 2.0}, [1.0, 0.01])
    assert mixed[0] == pytest.approx((hi - lo) / math.sqrt(12), rel=1e-3) and mixed[1] == pytest.approx(0.01 * mixed[0])
    assert np.isinf(sigma({"beta_n": 0.4, "exposure": 2.0}, [0, 1])[1])  # exposure alone: no upper end


def test_earlier_jacobians_take_the_jacobian_noise_out_of_the_steps():
    """A column whose Jacobian noise is twice its signal (fur_patch's β_n): met with the other pass's residual,
    that noise moves every step, and the steps along it scatter over four times as widely (in variance) as a
    noise-free Jacobian's would. With 30 earlier renders' Jacobians pooled in, they scatter nearly as the noise-free
    one's,
    still around the truth, and the pooled curvature is unbiased."""
    rng = np.random.default_rng(8)
    n, noise, jacobian_noise = 3999, 0.2, np.array([0.05, 0.2])
    jacobian = rng.standard_normal((n, 2)) * np.array([1.0, 0.1])
    exact = jacobian.T @ jacobian / n
    offset = np.array([0.01, -0.02])
    alone, pooled, curvatures = [], [], []
    for _ in range(300):
        lin = _noisy_linearization(rng, jacobian, offset, noise, jacobian_noise)
        earlier = jacobian + jacobian_noise * rng.standard_normal((30, n, 2))
        with_earlier = dataclasses.replace(lin, earlier_jacobians=earlier, curvature=None)
        alone.append(-np.linalg.solve(exact, lin.gradient))
        pooled.append(-np.linalg.solve(exact, with_earlier.gradient))
        curvatures.append(with_earlier.curvature)
    noise_free = noise**2 / (2 * n) * np.diag(np.linalg.inv(exact))  # the mean of two passes' residuals
    assert np.var(alone, axis=0)[1] > 3 * noise_free[1]
    np.testing.assert_allclose(np.var(pooled, axis=0), noise_free, rtol=0.3)
    np.testing.assert_allclose(np.mean(pooled, axis=0), -offset, atol=3 * np.sqrt(noise_free.max() / 300))
    np.testing.assert_allclose(np.mean(curvatures, axis=0), exact, rtol=0.02, atol=1e-4)


def test_step_covariance_predicts_the_scatter_of_gauss_newton_steps():
    rng = np.random.default_rng(6)
    n = 3999
    jacobian = rng.standard_normal((n, 3)) * np.array([1.0, 0.5, 0.2])
    steps, predicted = [], []
    for _ in range(300):
        lin = _noisy_linearization(rng, jacobian, np.array([0.01, -0.02, 0.03]), 0.2, 0.02)
        steps.append(-np.linalg.solve(lin.curvature, lin.gradient))
        predicted.append(lin.step_covariance)
    np.testing.assert_allclose(np.mean(steps, axis=0), [-0.01, 0.02, -0.03], atol=3e-3)
    np.testing.assert_allclose(np.diag(np.cov(np.array(steps).T)), np.diag(np.mean(predicted, axis=0)), rtol=0.25)


def test_a_trend_in_the_averaged_steps_is_seen_and_noise_rarely():
    """Points that creep along a line (a curved valley, a far start) are still moving; points that scatter
    about a fixed optimum mostly are not (at |t| > 3 with 3 or more degrees of freedom and 5 components, a few
    in ten are, which costs an extra step each, not a wrong answer)."""
    rng = np.random.default_rng(13)
    trend = [np.r_[0.01 * k, 0.0, 0.0, 0.0, 0.0] + 0.002 * rng.standard_normal(5) for k in range(8)]
    assert drifting(trend)
    assert not drifting(trend[:4])  # too few points to tell
    still = [drifting(list(0.01 * rng.standard_normal((8, 5)))) for _ in range(400)]
    assert np.mean(still) < 0.35


# ---------------------------------------------------------------------------------------------------------------
# Mini-batches


def test_a_mini_batch_loss_is_unbiased_for_the_whole_image():
    """The loss over a random set of blocks, divided by the whole image's scale, averages to the whole image's
    loss (a ratio of two subset means would not); masked pixels never enter a batch."""
    gen = torch.Generator().manual_seed(3)
    target = torch.rand(22, 18, 3, generator=gen) * torch.linspace(0.1, 2.0, 18)[None, :, None]
    image = target + 0.3 * torch.rand(22, 18, 3, generator=gen)
    mask = torch.ones(22, 18, dtype=torch.bool)
    mask[:5, :] = False
    batches = Batches(types.SimpleNamespace(image=target.numpy(), mask=mask.numpy()), pool=4, batch=64)
    assert batches.size == 4 and len(batches.blocks) == 25 and not batches.whole  # 6×5 blocks, the top 5 masked
    scale = loss_scale(target, "l2", mask, 4)
    whole = float(image_loss(image, target, "l2", mask, 4))
    draws = []
    for seed in range(3000):
        pixels, chosen = batches.draw(seed)
        assert not chosen[~mask].any() and chosen.sum() == len(pixels)
        draws.append(float(image_loss(image, target, "l2", chosen, 4, scale)))
    assert abs(np.mean(draws) - whole) < 4 * np.std(draws) / np.sqrt(len(draws))
    assert np.std(draws) > 0.05 * whole  # the batches do differ
    # Without the whole image's scale each batch is normalised by its own blocks: a biased ratio.
    ratio = [float(image_loss(image, target, "l2", batches.draw(seed)[1], 4)) for seed in range(3000)]
    assert abs(np.mean(ratio) - whole) > 4 * np.std(ratio) / np.sqrt(len(ratio))
    assert Batches(types.SimpleNamespace(image=target.numpy(), mask=None), pool=4, batch=None).draw(0) == (None, None)


def test_step_covariance_counts_the_correlation_of_a_pixels_channels():
    """A pixel's channels share their paths, so their noise correlates (here 0.8), and a control that moves all
    three alike (a β) gets (1 + 2·0.8)-fold the gradient noise that independent channels would give. The steps
    scatter as `step_covariance` predicts; the per-residual variances alone would predict less than half."""
    rng = np.random.default_rng(10)
    n = 3999
    jacobian = np.stack([np.repeat(rng.standard_normal(n // 3), 3), rng.standard_normal(n)], axis=1)
    steps, predicted, independent = [], [], []
    for _ in range(300):
        lin = _noisy_linearization(rng, jacobian, np.zeros(2), 0.2, 0.0, channel_correlation=0.8)
        steps.append(-np.linalg.solve(lin.curvature, lin.gradient))
        predicted.append(lin.step_covariance)
        h_inv, w, a = np.linalg.inv(lin.curvature), lin.loss_weights, lin.mean_jacobian
        independent.append(h_inv @ (a.T @ ((w * w * lin.mean_variance)[:, None] * a)) @ h_inv)
    measured = np.var(steps, axis=0)
    np.testing.assert_allclose(measured, np.diag(np.mean(predicted, axis=0)), rtol=0.25)
    assert measured[0] > 2 * np.diag(np.mean(independent, axis=0))[0]


def test_statistical_covariance_is_the_classical_one_for_independent_channels():
    """With independent, equally noisy residuals it is s² H⁻¹ (nonlinear least squares' covariance); with a
    pixel's channels correlated it grows along the control that moves them alike, as `step_covariance` does."""
    rng = np.random.default_rng(11)
    n = 3999
    jacobian = np.stack([np.repeat(rng.standard_normal(n // 3), 3), rng.standard_normal(n)], axis=1)
    lin = _noisy_linearization(rng, jacobian, np.zeros(2), 0.2, 0.0)
    lin = dataclasses.replace(lin, scatter=1e-5)
    np.testing.assert_allclose(lin.statistical_covariance, 1e-5 * np.linalg.inv(lin.curvature), rtol=0.1, atol=1e-6)
    correlated = dataclasses.replace(_noisy_linearization(rng, jacobian, np.zeros(2), 0.2, 0.0, 0.8), scatter=1e-5)
    ratio = np.diag(correlated.statistical_covariance) / np.diag(1e-5 * np.linalg.inv(correlated.curvature))
    assert ratio[0] > 2.0 and ratio[1] == pytest.approx(1.0, rel=0.15)


def test_mean_covariance_counts_the_scatter_the_model_leaves_out():
    """The mean of m end points has the model's covariance / m, scaled up when the points scatter more than the
    model says (the Jacobian's noise, which `step_covariance` leaves out), never down."""
    rng = np.random.default_rng(7)
    n = 3999
    jacobian = rng.standard_normal((n, 2))
    lin = _noisy_linearization(rng, jacobian, np.zeros(2), 0.2, 0.0)
    sigma = np.sqrt(np.diag(lin.step_covariance))
    for factor, expected in ((3.0, 9.0), (0.5, 1.0)):
        points = list(factor * sigma * rng.standard_normal((400, 2)))
        scale = np.diag(mean_covariance(points, lin)) / (np.diag(lin.step_covariance) / 400)
        np.testing.assert_allclose(scale, expected, rtol=0.15)
    few = list(3.0 * sigma * rng.standard_normal((3, 2)))  # too few to tell: the model alone
    np.testing.assert_allclose(mean_covariance(few, lin), lin.step_covariance / 3)


def test_a_large_images_sparse_gauss_newton_is_named_where_a_sigma_exceeds_its_bound():
    """Where the images hold more pixels than --batch, the Gauss–Newton renders run at fewer samples; where a σ
    then exceeds its acceptance bound the fit says so and names the --batch that renders every pixel at the full
    samples. Not where every σ is within its bound, nor where the renders already had the full samples."""
    from helpers.scenes import swatch_scene

    import warp_hair as wh
    from optimize.fit import FINAL_SPP_FACTOR, FitRun
    from optimize.target import Target, TargetImage
    from optimize.uncertainty import Uncertainty

    scene = swatch_scene(
        {"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.3},
        [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
        resolution=(16, 16),
        render_table={"spp": 8, "max_depth": 8, "seed": 1},
    )
    target = Target("tiny", None, [TargetImage("front", scene, wh.render(scene, spp=2, seed=11), None, None)], None)

    def note(batch, beta_n_sigma):
        run = FitRun(target, FitSettings(spp=16, batch=batch), progress=False)
        sigma = {"albedo": [0.01, 0.01, 0.01], "beta_m": 0.01, "beta_n": beta_n_sigma}
        return run.sparse_linearisation_note(Uncertainty(sigma, {}, {}, ()))

    text = note(64, 0.2)  # 256 pixels, a quarter of them per render: 16 spp instead of 64
    assert "beta_n" in text and "±0.2" in text and "--batch 256" in text and f"not {16 * FINAL_SPP_FACTOR}" in text
    assert note(64, 0.02) is None  # within its bound (0.03)
    assert note(256, 0.2) is None  # every pixel already at the full samples


def test_a_trade_off_between_two_controls_is_named_with_its_uncertainties():
    """Two columns nearly proportional (a change of one redone by the other) correlate their estimates beyond
    0.95 and draw a warning naming both with their σ; independent columns draw none."""
    rng = np.random.default_rng(9)
    n = 3999
    base = rng.standard_normal(n)
    for second, warned in ((base + 0.1 * rng.standard_normal(n), True), (rng.standard_normal(n), False)):
        lin = _noisy_linearization(rng, np.stack([base, second], axis=1), np.zeros(2), 0.2, 0.0)
        lin = dataclasses.replace(lin, values={"beta_m": 0.3, "beta_n": 0.4})
        result = estimate_uncertainty(lin)
        rho = result.correlations["beta_m/beta_n"]
        assert (abs(rho) > 0.95) == warned
        if warned:
            (message,) = result.warnings
            sigma = result.uncertainties
            assert message.startswith(f"beta_m and beta_n trade off in these images (correlation {rho:+.3f})")
            assert f"(±{sigma['beta_m']:.2g}, ±{sigma['beta_n']:.2g})" in message
        else:
            assert result.warnings == ()


def test_refine_steps_stay_inside_the_ranges():
    lo, hi = np.array([0.0, 0.01]), np.array([1.0, 1.0])
    x = np.array([0.9, 0.05])
    np.testing.assert_allclose(inside(x, np.array([0.02, -0.01]), lo, hi), [0.02, -0.01])  # short steps stay
    step = inside(x, np.array([0.3, -0.01]), lo, hi)  # albedo would pass 1: halfway to it, the same direction
    np.testing.assert_allclose(step, np.array([0.3, -0.01]) * (0.05 / 0.3))
    assert np.all(x + step > lo) and np.all(x + step < hi)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--fit", "albedo,beta"], "unknown control 'beta'"),
        (["--fit", "albedo,beta_m", "--fix", "beta_m=0.3"], r"\['beta_m'\] are both fixed \(--fix\) and fitted"),
        (["--init", "beta_m"], "--init takes NAME=VALUE"),
        (["--fix", "eta=abc"], "'abc' is not a number"),
    ],
)
def test_fit_command_errors(tmp_path, capsys, args, message):
    directory = write_target(tmp_path / "t")
    assert main(["fit", str(directory), "-o", str(tmp_path / "out"), "--iters", "1", *args]) == 2
    assert message.replace("\\", "") in capsys.readouterr().err.replace("\\", "") or pytest.fail(
        capsys.readouterr().err
    )


def test_fit_command_names_a_missing_target(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "nowhere"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "nowhere: no such target directory, nor a shipped target" in err and "blonde_straight" in err


# ---------------------------------------------------------------------------------------------------------------
# Shipped targets


def test_shipped_targets_are_complete():
    names = [d.name for d in shipped_targets()]
    own = ["auburn_curly", "black_straight", "blonde_straight", "brown_wavy", "chestnut_straight", "fur_patch"]
    # Hair as it grows (issue 44): lighter tips, one also with strands of their own colour.
    tips = ["auburn_light_tips_varied", "brown_light_tips"]
    peers = [f"mitsuba_{look}" for look in ("blonde_straight", "brown_straight", "dark_wavy")]
    # Cycles' draped swatches: light, medium and dark hair, straight, wavy and curly (issue 23's acceptance).
    peers += [
        f"cycles_{hair}_{shape}" for hair in ("blonde", "brown", "dark") for shape in ("straight", "wavy", "curly")
    ]
    # Cycles' own Random Color and Random Roughness on its melanin, dark, medium and light (issue 44).
    varied = [f"cycles_varied_{look}" for look in ("dark", "medium", "light")]
    peers += varied
    # The Cycles swatches as a camera saves them (benchmarks/make_photo_targets.py, issue 22).
    photos = [
        f"photo_{look}_{kind}"
        for look in ("blonde_straight", "brown_straight", "dark_wavy")
        for kind in ("jpeg", "png")
    ]
    # Swatches whose strands Blender made, rendered by Cycles, their scenes giving the recipe only, and the same
    # renders as a camera saves them through `warp-hair targets photo` (benchmarks/blender_swatch_acceptance.py).
    blender = ["blender_straight", "blender_wavy", "blender_clumped", "blender_thick"]
    blender_photos = ["blender_straight_png", "blender_wavy_jpeg", "blender_clumped_png", "blender_thick_jpeg"]
    assert names == sorted(own + tips + peers + photos + blender + blender_photos)
    for name in varied:
        truth = load_target(SHIPPED_TARGETS / name).truth
        assert truth.colour_input == "melanin" and truth.tip_absorption == 1.0
        assert 0.2 <= truth.color_spread <= 0.5 and 0.2 <= truth.roughness_spread <= 0.5
    for name in tips:
        truth = load_target(SHIPPED_TARGETS / name).truth
        assert truth.colour_input == "albedo" and 0.3 <= truth.tip_absorption <= 0.5
    assert load_target(SHIPPED_TARGETS / "auburn_light_tips_varied").truth.color_spread > 0.0
    for name in blender + blender_photos:
        target = load_target(SHIPPED_TARGETS / name)
        assert target.realisations == "random"
        assert (target.renderer == "cycles") == (name in blender)
        # The Blender photos carry their camera's EXIF exposures, which tie the views' gains.
        photo = ("exif", "fit") if name in blender_photos else ("none", "none")
        assert (target.gains, target.white_balance) == photo
        if name in blender_photos:
            assert all(image.coding == (8, "srgb", 1.0) for image in target.images)
    for name in photos:
        target = load_target(SHIPPED_TARGETS / name)
        assert (target.renderer, target.gains, target.white_balance) == ("cycles", "per-image", "fit")
        assert all(image.photo is not None and image.photo.bits == 8 for image in target.images)
    for name in peers:
        target = load_target(SHIPPED_TARGETS / name)
        assert target.renderer == name.split("_")[0]
        # Mitsuba's curves flip the tangent with the side hit: its targets are rendered without tilt.
        assert (target.hair.alpha == 0.0) == (target.renderer == "mitsuba")
    total = sum(f.stat().st_size for f in SHIPPED_TARGETS.rglob("*") if f.is_file())
    assert total < 4e6
    for directory in shipped_targets():
        target = load_target(directory)
        assert len(target.images) >= 2 and target.truth is not None
        if directory.name in blender_photos:
            # `targets photo` writes where a fit starts, not the truth it cannot know: the fixed controls agree.
            fixed = ("alpha", "eta", "r_roughness_scale")
            assert {k: target.truth.to_dict()[k] for k in fixed} == {k: target.hair.to_dict()[k] for k in fixed}
        else:
            assert target.truth.to_dict() == target.hair.to_dict()
    assert load_target(SHIPPED_TARGETS / "fur_patch").truth.r_roughness_scale != 1.0
    # A look-development-sized one, front- and back-lit, for the fit's mini-batches (issue 14).
    large = load_target(SHIPPED_TARGETS / "chestnut_straight")
    assert all(image.image.shape == (128, 128, 3) for image in large.images) and len(large.images) == 2


def test_the_varied_cycles_targets_state_the_look_cycles_rendered():
    """Each cycles_varied_* target was rendered from Cycles' own melanin inputs (its cycles_hair.toml, set in bpy by
    benchmarks/make_peer_targets.py); its truth is that look in our controls: Cycles' concentration −ln(1 − Melanin)
    split by Melanin Redness, in d'Eon's units. Cycles' absorption from its own coefficients (kernel/closure/
    bsdf_util.h, Blender 4.5) must be ours within 0.2% per channel (the two pigments' spectra differ, so that holds
    the split too), and the spreads are its Random Color and Random Roughness."""
    import tomllib

    cycles_eumelanin, cycles_pheomelanin = np.array([0.506, 0.841, 1.653]), np.array([0.343, 0.733, 1.924])
    for name in ("cycles_varied_dark", "cycles_varied_medium", "cycles_varied_light"):
        node = tomllib.loads((SHIPPED_TARGETS / name / "cycles_hair.toml").read_text(encoding="utf-8"))
        inputs = node["inputs"]
        assert node["parametrization"] == "MELANIN" and inputs["Coat"] == 0.0 and inputs["Tint"][:3] == [1.0] * 3
        target = load_target(SHIPPED_TARGETS / name)
        truth = target.truth
        concentration = -math.log(1.0 - inputs["Melanin"])
        redness = inputs["Melanin Redness"]
        theirs = concentration * ((1 - redness) * cycles_eumelanin + redness * cycles_pheomelanin)
        np.testing.assert_allclose(truth.absorption, theirs, rtol=2e-3)
        assert (truth.color_spread, truth.roughness_spread) == (inputs["Random Color"], inputs["Random Roughness"])
        assert (truth.beta_m, truth.beta_n, truth.eta) == (
            inputs["Roughness"],
            inputs["Radial Roughness"],
            inputs["IOR"],
        )
        assert truth.alpha == pytest.approx(math.degrees(inputs["Offset"]), abs=1e-12)
        assert target.renderer == "cycles" and truth.to_dict() == target.hair.to_dict()


def test_make_target_reproduces_the_committed_files(tmp_path):
    """`warp-hair targets make` must give back what is committed: re-render the cheapest shipped target."""
    source = SHIPPED_TARGETS / "black_straight"
    copy = shutil.copytree(source, tmp_path / "black_straight")
    for f in ("front.exr", "back.exr", "truth.json"):
        (copy / f).unlink()
    make_target(copy)
    assert (copy / "truth.json").read_text() == (source / "truth.json").read_text()
    for f in ("front.exr", "back.exr"):
        made, committed = read_exr(copy / f)[0], read_exr(source / f)[0]
        np.testing.assert_allclose(made, committed, rtol=1e-5, atol=1e-7)
