"""A fit never prints a confident wrong number (issue 42): Gauss–Newton steps that cannot make it worse, a measure
of fit against the noise model, and failures said as failures."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

from optimize import refine
from optimize.goodness import goodness_of_fit
from optimize.linearize import Linearization
from optimize.verdict import failures

N = 3 * 1200  # residuals, three to a pixel


def _linearization(rng, residual_mean, noise, jacobian=None, names=("beta_m", "beta_n")):
    """Two independent passes of residuals `residual_mean` + noise (per-residual σ `noise`), with `jacobian`."""
    n = len(residual_mean)
    residuals = residual_mean + noise * rng.standard_normal((2, n))
    jacobian = np.zeros((n, len(names))) if jacobian is None else jacobian
    return Linearization(
        values=dict.fromkeys(names, 0.5),
        residuals=residuals,
        variances=np.broadcast_to(noise**2, (2, n)).copy(),
        jacobians=np.stack([jacobian, jacobian]),
        images=[],
        loss_weights=np.full(n, 1.0 / n),
        image_residuals=(n,),
    )


def test_misfit_variance_predicts_the_misfits_scatter():
    """`misfit_variance` (what a step's change of the misfit is judged against) against the misfit's scatter
    over independent renders, with residuals far from zero (the first term) and at zero (the second)."""
    rng = np.random.default_rng(3)
    mean = np.concatenate([np.full(N // 2, 0.3), np.zeros(N // 2)])
    noise = np.full(N, 0.2)
    lins = [_linearization(rng, mean, noise) for _ in range(600)]
    scatter = np.var([lin.misfit for lin in lins], ddof=1)
    predicted = np.mean([lin.misfit_variance for lin in lins])
    assert predicted == pytest.approx(scatter, rel=0.15)


class _Model:
    """Residuals r = a · tanh((x₁ − 0.3)/W) + b · (x₂ − 0.4) + noise, with their exact Jacobian: a brightness
    that saturates away from the truth, as an image does when the albedo runs dark. From x₁ − 0.3 = 1.5 W,
    Newton's step lands at −3.5 W, on the plateau: the misfit rises, and the slope there is nearly zero, so the
    trapezoid rule on the slopes at both ends calls the step a descent (issue 42's photos: albedo to 0, gains to
    343, every step kept). `linear`: r = a · (x₁ − 0.3)/W + b · (x₂ − 0.4), where Gauss–Newton is exact."""

    truth = np.array([0.3, 0.4])
    W = 0.03

    def __init__(self, linear=False):
        rng = np.random.default_rng(8)
        self.a, self.b = rng.standard_normal(N), 0.6 * rng.standard_normal(N)
        self.linear, self.noise = linear, 0.02

    def mean(self, x):
        u = (x[0] - self.truth[0]) / self.W
        shape = u if self.linear else np.tanh(u)
        slope = 1.0 if self.linear else 1.0 - np.tanh(u) ** 2
        return self.a * shape + self.b * (x[1] - self.truth[1]), np.stack([self.a * slope / self.W, self.b], axis=1)

    def true_misfit(self, x) -> float:
        r, _ = self.mean(np.asarray(x, dtype=np.float64))
        return float(r @ r / N)

    def linearize(self, target, values, settings, spp, seed, threads=None, scenes=None, gain_columns=None):
        mean, jacobian = self.mean(np.array([values["beta_m"], values["beta_n"]]))
        lin = _linearization(np.random.default_rng(seed), mean, np.full(N, self.noise), jacobian)
        lin.values = dict(values)
        return lin


def _refined(monkeypatch, model, start):
    monkeypatch.setattr(refine, "linearize", model.linearize)
    run = refine.GaussNewton(None, start, types.SimpleNamespace(threads=None), spp=1, seed=0, steps=8)
    while not run.done:
        run.step()
    return run.result()


def test_gauss_newton_never_leaves_the_fit_worse(monkeypatch):
    """Steps are kept only when the misfit does not rise beyond its noise, and the result is no worse than the
    start: before, the overshooting step onto the plateau was kept by the slope test, and the next ran on to the
    range's bound."""
    model = _Model()
    start = {"beta_m": 0.3 + 1.5 * model.W, "beta_n": 0.42}
    result = _refined(monkeypatch, model, start)
    x = [result.values["beta_m"], result.values["beta_n"]]
    assert model.true_misfit(x) <= model.true_misfit(list(start.values()))
    assert not result.steps[0].accepted  # the step onto the plateau
    for step in result.steps:
        if step.accepted:
            assert step.change <= refine.MISFIT_Z * step.noise
    (start_misfit, s0), (end_misfit, s1) = result.start_misfit, result.end_misfit
    assert end_misfit <= start_misfit + refine.BEST_Z * np.hypot(s0, s1)


def test_gauss_newton_still_converges_where_the_linear_model_is_right(monkeypatch):
    """The rule costs nothing where Gauss–Newton is exact: the steps reach the optimum and are kept."""
    model = _Model(linear=True)
    result = _refined(monkeypatch, model, {"beta_m": 0.3 + 1.5 * model.W, "beta_n": 0.42})
    assert sum(step.accepted for step in result.steps) >= 7
    np.testing.assert_allclose([result.values["beta_m"], result.values["beta_n"]], model.truth, atol=1e-3)


def test_gradient_covariance_counts_the_jacobians_noise():
    """`gradient_covariance` (what the settled test weighs a gradient against) against the gradients' scatter over
    independent linearisations whose Jacobians are noisy and whose residuals do not vanish (a misfit):
    `noise_covariance`, which leaves the Jacobians' noise out, is half of it here."""
    rng = np.random.default_rng(1)
    n = 3 * 2000
    jacobian, misfit = rng.standard_normal((n, 2)), 0.05 * rng.standard_normal(n)
    lins = []
    for _ in range(400):
        lin = _linearization(rng, misfit, np.full(n, 0.1), jacobian)
        noisy = jacobian + 2.0 * rng.standard_normal((2, n, 2))
        lins.append(dataclasses.replace(lin, jacobians=noisy, curvature=None, scatter=None))
    scatter = np.cov(np.array([lin.gradient for lin in lins]).T)
    predicted = np.mean([lin.gradient_covariance for lin in lins], axis=0)
    np.testing.assert_allclose(np.diag(predicted), np.diag(scatter), rtol=0.15)
    assert np.all(np.diag(np.mean([lin.noise_covariance for lin in lins], axis=0)) < 0.7 * np.diag(scatter))


def test_chi2_quantile_is_scipys():
    from scipy.stats import chi2

    for dof in (1, 2, 3, 5, 8, 13):
        assert refine.chi2_quantile(refine.SETTLED, dof) == pytest.approx(chi2.ppf(refine.SETTLED, dof), rel=0.01)


def test_gauss_newton_averages_from_the_first_settled_point(monkeypatch):
    """From a start far off, the first steps land near the optimum but short of it by their damping (0.1% of the
    way, a dozen standard errors of this model's noise): those points are not settled, and the refinement
    averages the planned number of end points from the first that is, in fewer steps than planned (before: the
    later half of 8 steps whatever the first did); its estimate is within the Monte Carlo error it reports."""
    model = _Model(linear=True)
    monkeypatch.setattr(refine, "linearize", model.linearize)
    start = {"beta_m": 0.3 + 3 * model.W, "beta_n": 0.5}
    run = refine.GaussNewton(None, start, types.SimpleNamespace(threads=None), spp=1, seed=0, steps=8)
    while not run.done:
        run.step()
    result = run.result()
    assert len(run.averaged) == refine.averaged_points(8) == 4
    assert len(result.steps) < 8 and all(a is k for a, k in zip(run.averaged, run.kept[-4:]))
    error = np.array([result.values["beta_m"], result.values["beta_n"]]) - model.truth
    assert float(error @ np.linalg.solve(result.mc_covariance, error)) < 13.8  # χ² with 2 degrees of freedom, 0.999


def _target(shape=(48, 48), spp=1024):
    scene = types.SimpleNamespace(render=types.SimpleNamespace(spp=spp))
    image = np.random.default_rng(0).uniform(0.1, 1.0, (*shape, 3))
    return types.SimpleNamespace(
        images=[types.SimpleNamespace(name="front", image=image, mask=None, photo=None, from_photo=False, scene=scene)]
    )


def _pixel_linearization(rng, target, misfit):
    """Residuals per pixel of the target's one image (pool 1), with our noise and the target's (at its spp,
    from the same per-sample variance), plus `misfit` (H, W, 3)."""
    h, w = target.images[0].image.shape[:2]
    lin_spp, target_spp = 64, target.images[0].scene.render.spp
    per_sample = rng.uniform(0.5, 2.0, h * w * 3) * 0.05
    target_noise = np.sqrt(per_sample / target_spp) * rng.standard_normal(h * w * 3)
    ours = np.sqrt(per_sample / lin_spp) * rng.standard_normal((2, h * w * 3))
    residuals = misfit.reshape(-1) - target_noise + ours
    n = h * w * 3
    return Linearization(
        values={"beta_n": 0.3},
        residuals=residuals,
        variances=np.stack([per_sample / lin_spp] * 2),
        jacobians=np.zeros((2, n, 1)),
        images=[],
        loss_weights=np.full(n, 1.0 / n),
        image_residuals=(n,),
    )


def test_goodness_of_fit_is_one_for_noise_and_names_the_region_that_does_not_fit():
    rng = np.random.default_rng(4)
    target = _target()
    settings = types.SimpleNamespace(pool=1)
    ratios = [
        goodness_of_fit(_pixel_linearization(rng, target, np.zeros((48, 48, 3))), target, settings, 64).ratio
        for _ in range(20)
    ]
    assert abs(np.mean(ratios) - 1.0) < 0.03
    noise_only = goodness_of_fit(_pixel_linearization(rng, target, np.zeros((48, 48, 3))), target, settings, 64)
    assert not noise_only.significant and noise_only.birge == 1.0

    misfit = np.zeros((48, 48, 3))
    misfit[:16, :16] = 0.1  # the frame's top left does not fit
    bad = goodness_of_fit(_pixel_linearization(rng, target, misfit), target, settings, 64)
    assert bad.significant and bad.ratio > 2 and bad.birge == pytest.approx(np.sqrt(bad.ratio))
    assert bad.views[0].region == "the frame's top left" and bad.views[0].region_ratio > bad.ratio


def _goodness(ratio, significant=True, photo=False, view_ratio=None, view_significant=None):
    view = types.SimpleNamespace(
        name="back",
        ratio=ratio if view_ratio is None else view_ratio,
        significant=significant if view_significant is None else view_significant,
        region="its brightest third (the highlight)",
        region_ratio=9,
    )
    return types.SimpleNamespace(
        ratio=ratio, significant=significant, worst_view=lambda: view, views=(view,), photo=photo
    )


def test_verdict_names_each_failure_and_passes_a_good_fit():
    good = {"albedo": [0.3, 0.2, 0.1], "beta_m": 0.3, "beta_n": 0.4}
    falling = np.linspace(1.0, 0.1, 20)
    end = 0.05  # the fit's loss at its result
    assert failures(good, falling, end, None, None, _goodness(1.1, significant=False)) == []

    [reason] = failures({**good, "albedo": [0.0004, 0.002, 0.3]}, falling, end, None, None, None)[:1]
    assert "albedo[r] ran to the end of its range" in reason
    [reason] = failures(good, falling, 1.2, None, None, None)
    assert "loss ended above where it started (1 -> 1.2)" in reason
    assert failures(good, falling[::-1], end, None, None, None) == []  # the descent may rise; the fit's end counts
    camera = {
        "gains": {"front": [2.0, 0.1], "back": [550.0, 60922.0]},
        "white_balance": {"value": [1, 1, 1], "sigma": [0, 0, 0]},
    }
    [reason] = failures(good, falling, end, None, camera, None)
    assert "gain of view back ran to 550" in reason
    [reason] = failures(good, falling, end, None, None, _goodness(6.0))
    assert "does not describe the images" in reason and "view back" in reason and "brightest third" in reason
    assert "JPEG" not in reason and "JPEG" in failures(good, falling, end, None, None, _goodness(6.0, photo=True))[0]
    assert failures(good, falling, end, None, None, _goodness(1.3)) == []  # above noise, below FAILED_CHI2: σ scaled
    # One view the look does not describe fails the fit though the total, with a view that fits, stays below.
    [reason] = failures(good, falling, end, None, None, _goodness(0.8, False, view_ratio=1.7, view_significant=True))
    assert "does not describe the images" in reason and "view back (1.7)" in reason
    assert failures(good, falling, end, None, None, _goodness(0.8, False, view_ratio=1.7, view_significant=False)) == []
    refinement = types.SimpleNamespace(start_misfit=(0.041, 0.001), end_misfit=(0.089, 0.001))
    [reason] = failures(good, falling, end, refinement, None, None)
    assert "ended worse than it started" in reason
    [reason] = failures({**good, "tip_length": 0.5}, falling, end, None, None, None, ("tip_length",))
    assert "tip_length does not change the rendered images" in reason and "--fix" in reason
    # A spread's 0 is the end of its range and its default: no variation, a value like any other.
    assert failures({**good, "color_spread": 1e-5}, falling, end, None, None, None) == []
    [reason] = failures(good, falling, end, None, None, _goodness(6.0))
    assert "--fit albedo,beta_m,beta_n,color_spread,roughness_spread" in reason and "tip_absorption" in reason


def _swapped_target(tmp_path):
    """black_straight with its back-lit image in place of the front-lit one: no look renders both views so."""
    import shutil

    from optimize.target import SHIPPED_TARGETS

    folder = tmp_path / "swapped"
    shutil.copytree(SHIPPED_TARGETS / "black_straight", folder)
    shutil.copy(folder / "back.exr", folder / "front.exr")
    return folder


def test_a_fit_the_images_contradict_exits_failed_and_says_why(tmp_path):
    """The command a user runs: exit status 3, the reason and what to try on stderr, params.json marked failed."""
    import json
    import subprocess
    import sys

    out = tmp_path / "out"
    command = [sys.executable, "-m", "optimize.cli", "fit", str(_swapped_target(tmp_path)), "-o", str(out)]
    done = subprocess.run(
        [*command, "--iters", "8", "--spp", "4", "--refine", "2", "--threads", "2"], capture_output=True, text=True
    )
    assert done.returncode == 3, done.stderr
    assert "does not describe the images" in done.stderr and "FAILED" in done.stderr
    assert "goodness of fit: chi2/dof" in done.stdout
    params = json.loads((out / "params.json").read_text())
    assert params["failed"] and params["failures"] and params["goodness_of_fit"]["chi2_per_dof"] > 4


def test_a_failed_fit_in_a_batch_is_a_failed_job_with_its_files(tmp_path):
    """`warp-hair batch` records a failed fit as failed, with its reason, and keeps its params.json and pictures
    to look at (optimize/batch/jobs.py)."""
    from optimize.batch.jobs import _fit
    from optimize.settings import FitSettings
    from optimize.target import load_target

    target = load_target(_swapped_target(tmp_path))
    outcome = _fit(types.SimpleNamespace(spec={"export": []}), target, FitSettings(iters=8, spp=4, refine=2), 2)
    assert outcome["error"].startswith("the fit failed: the fitted look does not describe the images")
    assert {"params.json", "convergence.png", "comparison.png"} <= set(outcome["files"])
