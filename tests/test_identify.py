"""`warp-hair targets check`: whether a target's images identify its controls (optimize/identify.py)."""

import copy
import dataclasses
import json

import numpy as np
import pytest
from helpers.scenes import front_camera, toml_text

from optimize.cli import _check_values, main
from optimize.fit import FitSettings, gauss_newton_spp
from optimize.identify import Identifiability, _problems, check_target, describe
from optimize.linearize import linearize, loss_weights, pool_like_loss
from optimize.refine import JACOBIAN_WINDOW
from optimize.settings import ALBEDO_BOUND, BETA_BOUND, BOUNDS
from optimize.target import SHIPPED_TARGETS, load_target, make_target
from warp_hair.realisation import realisation
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render

HAIR = {"albedo": [0.7, 0.5, 0.3], "beta_m": 0.3, "beta_n": 0.4}


def write_target(directory, lights, drape, spp, hair=HAIR):
    """A 60-fiber swatch (flat without drape) seen head-on, one 16×16 image per light, rendered by warp-hair."""
    directory.mkdir()
    entries = []
    for k, direction in enumerate(lights):
        (directory / f"scene_{k}.toml").write_text(
            toml_text(
                {
                    "camera": front_camera(0.2, (16, 16)),
                    "lights": [{"type": "directional", "direction": direction, "irradiance": [3.0, 3.0, 3.0]}],
                    "fibers": {
                        "generator": "swatch",
                        "count": 60,
                        "layers": 3,
                        "length": 0.4,
                        "width": 0.24,
                        "radius": 0.004,
                        "segments": 12,
                        "seed": 2,
                        **({"drape": drape} if drape else {}),
                    },
                    "hair": hair,
                    "render": {"spp": spp, "max_depth": 16, "seed": 3},
                }
            )
        )
        entries.append(f'[[images]]\nscene = "scene_{k}.toml"\nimage = "image_{k}.exr"\n')
    (directory / "target.toml").write_text("\n".join(entries))
    make_target(directory, threads=1)
    return directory


def test_the_bounds_are_the_acceptance_bounds():
    assert {name: BOUNDS[name] for name in ("albedo", "beta_m", "beta_n")} == {
        "albedo": ALBEDO_BOUND,
        "beta_m": BETA_BOUND,
        "beta_n": BETA_BOUND,
    }
    assert (ALBEDO_BOUND, BETA_BOUND) == (0.02, 0.03)
    assert {BOUNDS[name] for name in ("color_spread", "roughness_spread", "tip_absorption")} == {0.05}  # issue 44


def test_a_flat_swatch_seen_head_on_under_a_front_light_is_a_bad_target(tmp_path, capsys):
    """One angle between light, fiber and camera: albedo, β_m and β_n trade off, and no number of samples tells
    them apart. The check fails it (exit status 1), naming the controls and what to add."""
    directory = write_target(tmp_path / "flat", [[0.0, 0.0, -1.0]], None, 64)
    assert main(["targets", "check", str(directory), "--threads", "1"]) == 1
    captured = capsys.readouterr()
    assert "is a bad target: its images do not pin down albedo[r]" in captured.err
    assert "not identifiable" in captured.out and "add a view that tells them apart" in captured.out
    result = check_target(load_target(directory), threads=1)
    assert not result.identifiable
    assert np.all(result.sigma[:3] > ALBEDO_BOUND) and max(abs(c[1]) for c in result.correlation) > 0.95


def test_brown_wavy_is_identifiable():
    """The shipped brown_wavy (front- and back-lit, draped, 1024 spp) pins every control down well within the
    bounds: by the check, and by its fits (docs/acceptance.md: errors 0.003 and below)."""
    target = load_target(SHIPPED_TARGETS / "brown_wavy")
    result = check_target(target, render_spp=16, linearisations=2, threads=1)
    assert result.identifiable, result.problems
    assert result.model_error == 0.0 and result.target_spp == [1024, 1024]
    assert np.all(result.sigma < 0.25 * result.bounds)


def test_the_expected_sigma_is_the_scatter_that_the_targets_own_noise_gives_the_estimate(tmp_path):
    """Render the target anew with 200 seeds at its spp: the least-squares estimate from each (one step of the
    linearised loss, the same renders of ours throughout) scatters by what the check expects from one render of
    it. Albedo and β_m only: with β_n too, albedo and β_n trade off here, and along that valley both σ's hang on
    the curvature's smallest eigenvalue, which even 8 renders at 1024 spp leave uncertain by 10%. The check's σ
    comes from 4 × 2 renders over 128 pooled blocks and scatters over its seeds by 2–3% (albedo) and 5% (β_m), so
    the mean of 4 seeds is compared (±1.5–2.7%); the scatter from 200 targets (±5%): within 15%."""
    directory = write_target(tmp_path / "draped", [[0.2, -0.3, -1.0], [0.0, -0.15, 1.0]], 0.15, 32)
    target = load_target(directory)
    settings = FitSettings(pool=2)
    controls = {"albedo": HAIR["albedo"], "beta_m": HAIR["beta_m"]}
    expected = np.mean(
        [
            check_target(target, controls=tuple(controls), settings=settings, render_spp=32, threads=1, seed=s).noise
            for s in range(4)
        ],
        axis=0,
    )
    lin = linearize(target, controls, settings, spp=256, seed=9, threads=1)
    scenes = [prepare(image.scene) for image in target.images]
    draws = [(scenes, 1000 + seed) for seed in range(200)]
    scatter = _estimate_scatter(target, settings, lin, draws, spp=32, threads=1)
    np.testing.assert_allclose(expected, scatter, rtol=0.15)


def test_the_fits_part_is_the_scatter_its_own_renders_give_its_steps(tmp_path):
    """A fit's estimate is the mean of m Gauss–Newton end points, each moved from the optimum by its own renders'
    noise. Linearise 60 times at the truth at the fit's samples per render: the one-step estimates H⁻¹ Aᵀ W r̄
    (H and A steady, from 256 spp, so that only the residuals' render noise moves them) scatter by √m times the
    fit's part the check expects, which it takes from renders at another spp (32 here against the fit's 8).
    Sampling error: ±9% for the scatter of 60, ±5% for the check's: within 25%. The steps as the fit takes them,
    with A pooled over JACOBIAN_WINDOW linearisations (`refine.py`), scatter more, by the Jacobians' own noise,
    which the check leaves out: its part is a lower bound (here by up to 30% on β_m: 8 spp on 16×16 pixels)."""
    directory = write_target(tmp_path / "draped", [[0.2, -0.3, -1.0], [0.0, -0.15, 1.0]], 0.15, 32)
    target = load_target(directory)
    settings = FitSettings(pool=2, spp=2)
    controls = {"albedo": HAIR["albedo"], "beta_m": HAIR["beta_m"]}
    result = check_target(target, controls=tuple(controls), settings=settings, render_spp=32, threads=1)
    spp = gauss_newton_spp(settings, target)
    assert (spp, result.fit_points) == (8, 4)
    steady = linearize(target, controls, settings, spp=256, seed=9, threads=1)
    h_inv, a, w = np.linalg.inv(steady.curvature), steady.mean_jacobian, steady.loss_weights
    lins = [linearize(target, controls, settings, spp=spp, seed=100 + 7919 * k, threads=1) for k in range(60)]
    steps = [h_inv @ (a.T @ (w * lin.mean_residual)) for lin in lins]
    np.testing.assert_allclose(result.fit_noise, np.std(steps, axis=0, ddof=1) / 2, rtol=0.25)
    window = [
        dataclasses.replace(
            lin, earlier_jacobians=np.concatenate([e.jacobians for e in lins[k - JACOBIAN_WINDOW + 1 : k]])
        )
        for k, lin in enumerate(lins)
        if k >= JACOBIAN_WINDOW - 1
    ]
    pooled = np.std([h_inv @ lin.gradient for lin in window], axis=0, ddof=1) / 2
    assert np.all(pooled > 0.8 * result.fit_noise), (pooled, result.fit_noise)
    assert np.all(result.sigma**2 >= result.noise**2 + result.fit_noise**2 - 1e-12)


def _estimate_scatter(target, settings, lin, draws, spp, threads):
    """(p,): the scatter of the least-squares estimate (one step of `lin`'s linearised loss) over targets
    rendered anew, one per (prepared scenes of the images, seed) in `draws`."""
    h_inv = np.linalg.inv(lin.curvature)
    # The loss's weights are the target's, one factor per image that does not move the minimum: the committed
    # target's weights serve for every render of it.
    weights = [
        loss_weights(pool_like_loss(image, image.image, None, settings.pool)[0], settings.loss)
        for image in target.images
    ]
    estimates = []
    for scenes, seed in draws:
        t = []
        for image, scene, weight in zip(target.images, scenes, weights):
            pooled, _ = pool_like_loss(image, render(scene, spp=spp, seed=seed, threads=threads), None, settings.pool)
            t.append(pooled * weight)
        # The target enters the gradient as −Aᵀ W t: the estimate moves by H⁻¹ Aᵀ W t.
        estimates.append(h_inv @ lin.crossed(np.stack([np.concatenate(t)] * 2)))
    return np.std(estimates, axis=0, ddof=1)


def test_the_check_needs_values_to_check_at(tmp_path, capsys):
    directory = write_target(tmp_path / "t", [[0.2, -0.3, -1.0]], 0.15, 8)
    (directory / "truth.json").unlink()
    assert main(["targets", "check", str(directory)]) == 2
    assert (
        "no true value for albedo, beta_m, beta_n (the target has no truth.json); give the look to check at: --at "
        "NAME=V ... (the look you expect), or a quick fit's estimate, --at FIT_DIR/params.json (e.g. `warp-hair fit "
        f"{directory} -o quick --iters 30 --refine 2`)" in capsys.readouterr().err
    )
    assert main(["targets", "check", str(directory), "--realisation-samples", "1"]) == 2
    assert "realisation samples must be an integer >= 2, got 1" in capsys.readouterr().err
    target = load_target(directory)
    with pytest.raises(ValueError, match=r"values given for \['eta'\], which are not checked"):
        check_target(copy.deepcopy(target), {**HAIR, "eta": 1.5})
    result = check_target(target, HAIR, spp=4096, render_spp=8, linearisations=2, threads=1)
    assert result.target_spp == [4096]
    # The fit of a target at 4096 spp takes 16 Gauss-Newton steps (fit.refine_steps), not its own 8 spp's 8: the
    # check counts the mean of their later 8 points.
    assert (result.fit_points, result.fit_spp) == (8, 64)


def test_over_random_realisations_the_expected_sigma_counts_the_targets_strands(tmp_path):
    """A target whose scenes give its strands by their recipe only (realisations = "random"): its strands are one
    draw of that recipe. Draw 60 targets (other realisations, rendered at the target's spp): their estimates
    (one step of the linearised loss, the same renders of ours throughout) scatter by more than twice what the
    target's noise gives, and by what the check expects with the strands' draw counted. Dark hair and β_n,
    where the strands' placement moves the estimate most (docs/acceptance.md, dark straight). Sampling error:
    the scatter of 60 draws ±9%, the check's part from 48 realisations about ±14%: within 35%."""
    dark = {"albedo": [0.12, 0.09, 0.07], "beta_m": 0.25, "beta_n": 0.3}
    directory = write_target(tmp_path / "dark", [[0.2, -0.3, -1.0], [0.0, -0.15, 1.0]], 0.15, 256, dark)
    spec = directory / "target.toml"
    spec.write_text('realisations = "random"\n' + spec.read_text())
    target = load_target(directory)
    settings = FitSettings(pool=2)
    controls = {"beta_n": dark["beta_n"]}
    result = check_target(target, controls=tuple(controls), settings=settings, threads=2, realisation_samples=48)
    assert result.realisation_samples == 48 and result.target_spp == [256, 256]
    fixed = check_target(target, controls=tuple(controls), settings=settings, threads=2, realisations="fixed")
    assert fixed.realisation is None and "strands' draw" not in describe(fixed)
    assert "σ strands' draw" in describe(result)

    lin = linearize(target, controls, settings, spp=2048, seed=9, threads=2)
    draws = (([prepare(realisation(image.scene, 1000 + k)) for image in target.images], 500 + k) for k in range(60))
    scatter = _estimate_scatter(target, settings, lin, draws, spp=256, threads=2)
    assert np.all(scatter > 2 * result.noise)
    np.testing.assert_allclose(result.sigma, scatter, rtol=0.35)


def test_the_check_reads_a_fits_look_from_its_params_json(tmp_path, capsys):
    """--at FIT_DIR (or its params.json): the look a quick fit left, of the controls checked; NAME=V overrides."""
    fit_dir = tmp_path / "quick"
    fit_dir.mkdir()
    look = {"albedo": [0.5, 0.4, 0.3], "beta_m": 0.28, "beta_n": 0.33, "alpha": 2.0, "eta": 1.55}
    (fit_dir / "params.json").write_text(json.dumps({"look": look}))
    names = ("albedo", "beta_m", "beta_n")
    assert _check_values([str(fit_dir)], names) == {"albedo": [0.5, 0.4, 0.3], "beta_m": 0.28, "beta_n": 0.33}
    assert _check_values([str(fit_dir / "params.json"), "beta_n=0.4"], names)["beta_n"] == [0.4]
    directory = write_target(tmp_path / "t", [[0.2, -0.3, -1.0]], 0.15, 8)
    (fit_dir / "params.json").write_text(json.dumps({"fitted": {}}))
    assert main(["targets", "check", str(directory), "--at", str(fit_dir)]) == 2
    assert f"--at {fit_dir}: not NAME=V and not a fit's params.json" in capsys.readouterr().err
    assert main(["targets", "check", str(directory), "--at", str(tmp_path / "none.json")]) == 2
    assert "none.json: not NAME=V and not a fit's params.json (or its directory)" in capsys.readouterr().err


PHOTO_TERMS = ("grey card in the shot", "photograph", "more hair in view", "shots of each view averaged")


def test_a_photo_targets_advice_is_a_photographers():
    """The light photo-like swatch (its PNGs as a camera saves them, front- and back-lit): its red albedo is not
    pinned, and the check says what to photograph (a grey card, EXIF exposures, another view, more hair in view,
    less noise), never to render it with more samples; the same account for a render says to render it so."""
    target = load_target(SHIPPED_TARGETS / "photo_blonde_straight_png")
    result = check_target(target, render_spp=4, linearisations=2, threads=2)
    assert result.photo and result.views == 2 and not result.card
    advice = {problem.split(":")[0]: problem for problem in result.problems}
    assert "albedo[r]" in advice
    assert all(term in advice["albedo[r]"] for term in PHOTO_TERMS) and 'gains = "exif"' in advice["albedo[r]"]
    assert "render the target" not in describe(result) and "more samples" not in describe(result)
    rendered = _problems(dataclasses.replace(result, photo=False), ~np.isfinite(result.noise))
    assert "render the target with" in rendered[0] and not any(term in rendered[0] for term in PHOTO_TERMS)


def _account(**parts):
    """An Identifiability of five controls whose σ parts are `parts` (each (5,)), the rest 0."""
    zero = np.zeros(5)
    fields = {
        "target": "t", "origin": "unknown", "values": {"albedo": [0.5] * 3, "beta_m": 0.3, "beta_n": 0.3},
        "labels": ["albedo[r]", "albedo[g]", "albedo[b]", "beta_m", "beta_n"], "target_spp": [1024],
        "noise": zero, "shift": zero, "model_error": 0.01, "correlation": [None] * 5,
        "bounds": np.array([0.02, 0.02, 0.02, 0.03, 0.03]), "realisation": zero, "realisation_samples": 24,
        "fit_noise": zero, "fit_points": 8, "fit_spp": 64, "photo": True, "gains": "none", "views": 1,
        "quantisation": zero,
    }  # fmt: skip
    return Identifiability(**{**fields, **parts})


def test_every_cause_has_a_photographers_remedy():
    """Per cause of a control's σ: the images not changing with it (β_m), a brightness disagreement with no gains
    fitted (albedo[r]), the photos' 8-bit codes (albedo[g]), the strands' draw (β_n), the fit's own renders beside
    the photos' noise (albedo[b]): a photographer's remedy for a photo, the renderer's for a render."""
    result = _account(
        noise=np.array([0.001, 0.03, 0.025, np.inf, 0.001]),
        shift=np.array([0.025, 0.0, 0.0, 0.0, 0.0]),
        quantisation=np.array([0.0, 0.028, 0.0, 0.0, 0.0]),
        realisation=np.array([0.0, 0.0, 0.0, 0.0, 0.05]),
        fit_noise=np.array([0.0, 0.0, 0.03, 0.0, 0.0]),
    )
    flat = np.array([False, False, False, True, False])
    photo = dict(zip(result.labels, _problems(result, flat)))
    assert photo["albedo[r]"].endswith(
        'fit the photos\' exposures (gains = "per-image" in target.toml, or "exif" where every photo has its EXIF '
        "exposure), which absorb a uniform disagreement, or photograph a view in which it changes the image "
        "otherwise than brightness does (front- and back-lit)"
    )
    assert "16-bit TIFF or raw photos (the 8-bit codes' rounding alone gives σ 0.028)" in photo["albedo[g]"]
    assert "a back-lit view besides the front-lit one" in photo["albedo[g]"]
    assert "grey card" not in photo["albedo[g]"]  # gains = "none": nothing to fix
    assert "better photos of the same views do not change" in photo["albedo[b]"]
    # Half of what is left each: the fit's 0.03 down to 0.02/√2 takes 8 · (0.03² / 0.0002) = 36 points, 72 steps.
    assert "Gauss-Newton steps alone would take about 72 (--refine 72)" in photo["albedo[b]"]
    assert photo["beta_m"].endswith(
        "photograph a view in which it shows (front- and back-lit: a light behind the swatch shows the light that "
        "went through the fibers), or fix it (leave it out of --fit)"
    )
    assert "get more strands in view (a wider crop of the swatch, or the camera further back" in photo["beta_n"]
    assert 'realisations = "fixed"' not in photo["beta_n"] and "[arrangement]" not in photo["beta_n"]
    # With a prior over how the strands lie, part of the draw does not fall with more strands: narrow it.
    prior = dict(zip(result.labels, _problems(dataclasses.replace(result, arrangement=("jitter", "layer_gap")), flat)))
    assert "target.toml's [arrangement]: jitter, layer_gap), which moves every strand at once" in prior["beta_n"]
    rendered = dict(zip(result.labels, _problems(dataclasses.replace(result, photo=False), flat)))
    assert "fit exposure as well" in rendered["albedo[r]"] and "render the target with" in rendered["albedo[g]"]
    assert 'realisations = "fixed"' in rendered["beta_n"] and "add a view or a light" in rendered["beta_m"]
    assert not any(term in text for text in rendered.values() for term in PHOTO_TERMS)
