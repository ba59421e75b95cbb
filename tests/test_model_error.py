"""The model-error term of the fit's uncertainty: the estimate's sensitivity to a brightness disagreement between
the renderer that made the target and ours (optimize/uncertainty.py), its setting, and where it is reported."""

import copy
import json
import types

import numpy as np
import pytest
from helpers.scenes import small_swatch_text, write_front_back_target

from optimize.cli import main
from optimize.fit import FitSettings, check_settings
from optimize.linearize import Linearization, linearize
from optimize.report import format_table, write_params
from optimize.target import load_target, make_target
from optimize.uncertainty import (
    PEER_MODEL_ERROR,
    brightness_sensitivity,
    estimate_uncertainty,
    target_model_error,
)
from warp_hair.io import write_exr
from warp_hair.renderer.prepare import prepare

TRUTH = {"albedo": [0.6, 0.42, 0.25], "beta_m": 0.3, "beta_n": 0.4}


def swatch_text(direction, spp=64):
    return small_swatch_text(direction, TRUTH, spp)


@pytest.fixture(scope="module")
def own_target(tmp_path_factory):
    """Front- and back-lit, rendered by warp-hair (`make_target`, which records it in the EXR headers)."""
    directory = write_front_back_target(tmp_path_factory.mktemp("own"), swatch_text)
    make_target(directory, threads=1)
    return directory


# ---------------------------------------------------------------------------------------------------------------
# The sensitivity


def _analytic_problem(rng, n=600, p=3):
    """A smooth nonlinear least-squares problem in the shape of a linearisation: renders I(x) = c·exp(B x), the
    target their value at x0 with a little noise, and two "passes" whose residuals and Jacobians carry fixed,
    independent render noise (so that the crossed products are exercised, and the fixed point is smooth in x)."""
    b = 0.5 * rng.standard_normal((n, p))
    c = rng.uniform(5.0, 15.0, n)  # radiances far from 1, so that a missing weight would show
    x0 = np.array([0.2, -0.1, 0.3])
    target = c * np.exp(b @ x0) * (1 + 0.002 * rng.standard_normal(n))
    render_noise = 0.002 * rng.standard_normal((2, n))
    jacobian_noise = 0.002 * rng.standard_normal((2, n, p))

    def linearised(x, scale):
        t = scale * target
        weight = 1.0 / np.sqrt(np.mean(t * t))  # the L2 loss's weight, from the target as it is given
        image = c * np.exp(b @ x)
        return Linearization(
            values={},
            residuals=weight * (image + render_noise - t),
            variances=np.zeros((2, n)),
            jacobians=weight * ((image[:, None] * b) + jacobian_noise),
            images=[],
            loss_weights=np.full(n, 1.0 / n),
            targets=weight * t,
            image_residuals=(n,),
        )

    return x0, linearised


def _gauss_newton(linearised, x, scale):
    for _ in range(50):
        lin = linearised(x, scale)
        step = -np.linalg.solve(lin.curvature, lin.gradient)
        x = x + step
        if np.abs(step).max() < 1e-14:
            return x
    raise AssertionError("Gauss–Newton did not converge")


def test_sensitivity_is_the_shift_of_the_least_squares_estimate_when_the_target_brightens():
    """Fit a nonlinear problem to its target and to the target 1% brighter and 1% darker, each to convergence:
    the estimate moves by ±0.01 s, s from the linearisation at the first fit (sign, weights and the loss's
    renormalisation by the target included). The central difference leaves what the linearisation leaves out:
    the residuals' curvature, which the target's 0.2% noise keeps to a few parts in a thousand here."""
    x0, linearised = _analytic_problem(np.random.default_rng(3))
    fitted = _gauss_newton(linearised, x0, 1.0)
    brighter, darker = _gauss_newton(linearised, fitted, 1.01), _gauss_newton(linearised, fitted, 0.99)
    sensitivity = brightness_sensitivity(linearised(fitted, 1.0))
    assert np.abs(sensitivity).min() > 0.05  # each control moves, so the comparison below means something
    np.testing.assert_allclose((brighter - darker) / 0.02, sensitivity, rtol=5e-3)


def test_a_brighter_target_is_taken_for_a_higher_albedo_and_the_weights_do_not_care(own_target):
    """With the same renders, the target scaled by 1.01 leaves the weighted target of every residual alone (L2
    divides by the target's RMS, relative L2 by the target itself): a uniform brightness disagreement enters
    only through the residuals. The sensitivity says a brighter target raises every albedo channel."""
    target = load_target(own_target)
    scaled = copy.deepcopy(target)
    for image in scaled.images:
        image.image = image.image * np.float32(1.01)
    scenes = [prepare(image.scene) for image in target.images]
    for loss in ("l2", "rel_l2"):
        settings = FitSettings(loss=loss)
        lin = linearize(target, TRUTH, settings, spp=8, seed=4, threads=1, scenes=scenes)
        lin_scaled = linearize(scaled, TRUTH, settings, spp=8, seed=4, threads=1, scenes=scenes)
        np.testing.assert_allclose(lin_scaled.targets, lin.targets, rtol=1e-5)
        # ρ' = ω/1.01 · (I − 1.01 T) = (r + t)/1.01 − t
        np.testing.assert_allclose(
            lin_scaled.residuals, (lin.residuals + lin.targets) / 1.01 - lin.targets, rtol=1e-5, atol=1e-7
        )
        assert np.all(brightness_sensitivity(lin)[:3] > 0)


def test_exposure_absorbs_a_uniform_brightness_disagreement(own_target):
    """A target (1 + ε) times as bright is (1 + ε) times the gain: fitted, exposure takes it all (its
    sensitivity is the gain itself) and the hair controls none, where without exposure albedo takes it. At a
    gain of 1.3, so that a Jacobian column of gain·I in place of ∂r/∂gain = ω·I would show."""
    target = load_target(own_target)
    scenes = [prepare(image.scene) for image in target.images]
    without = brightness_sensitivity(linearize(target, TRUTH, FitSettings(), spp=8, seed=6, threads=1, scenes=scenes))
    lin = linearize(target, {**TRUTH, "exposure": 1.3}, FitSettings(), spp=8, seed=6, threads=1, scenes=scenes)
    sensitivity = brightness_sensitivity(lin)
    assert sensitivity[-1] == pytest.approx(1.3, rel=1e-6)
    assert np.abs(without[:3]).min() > 0.1
    np.testing.assert_allclose(sensitivity[:-1], 0.0, atol=1e-6 * np.abs(without).max())


# ---------------------------------------------------------------------------------------------------------------
# In the uncertainty


def _linearization(rng, n=999):
    jacobian = rng.standard_normal((n, 2)) * np.array([1.0, 0.3])
    residuals = 0.05 * rng.standard_normal((2, n))
    jacobians = jacobian + 0.01 * rng.standard_normal((2, n, 2))
    return Linearization(
        values={"beta_m": 0.3, "beta_n": 0.4},
        residuals=residuals,
        variances=np.full((2, n), 0.05**2),
        jacobians=jacobians,
        images=[],
        loss_weights=np.full(n, 1.0 / n),
        targets=rng.uniform(0.5, 1.5, n),
        image_residuals=(n,),
    )


def _estimated(lin, model_error, mc):
    return estimate_uncertainty(lin, mc, model_error)


def test_model_error_adds_its_own_part_and_zero_adds_nothing():
    """ε = 0 reports the noise's σ exactly as before the model term; ε > 0 the diagonal of Cov + ε² s sᵀ, with
    the noise and model parts apart and the correlations still the noise's."""
    rng = np.random.default_rng(12)
    lin = _linearization(rng)
    mc = np.diag([1e-6, 4e-6])
    none = _estimated(lin, 0.0, mc)
    noise = np.sqrt(np.diag(lin.statistical_covariance + mc))
    assert [none.uncertainties["beta_m"], none.uncertainties["beta_n"]] == noise.tolist()
    assert none.parts["model"] == {"beta_m": 0.0, "beta_n": 0.0}

    some = _estimated(lin, 0.02, mc)
    s = brightness_sensitivity(lin)
    expected = np.sqrt(np.diag(lin.statistical_covariance + mc + 0.02**2 * np.outer(s, s)))
    np.testing.assert_allclose([some.uncertainties["beta_m"], some.uncertainties["beta_n"]], expected, rtol=1e-12)
    assert some.parts["noise"] == none.uncertainties
    np.testing.assert_allclose(list(some.parts["model"].values()), 0.02 * np.abs(s), rtol=1e-12)
    np.testing.assert_allclose(list(some.parts["shift_per_percent_brightness"].values()), 0.01 * s)
    assert some.correlations == none.correlations and some.parts["model_error"] == 0.02


def test_the_model_part_is_written_and_printed():
    rng = np.random.default_rng(13)
    result = _estimated(_linearization(rng), 0.01, None)
    fit_result = types.SimpleNamespace(
        values={"beta_m": 0.31, "beta_n": 0.39}, uncertainties=result.uncertainties, uncertainty_parts=result.parts
    )
    table = format_table(fit_result, {"beta_m": 0.3, "beta_n": 0.4}, "mitsuba")
    header = table.splitlines()[0].split("  ")
    assert [cell.strip() for cell in header if cell.strip()] == [
        "control",
        "fitted",
        "± 1σ",
        "± noise",
        "± model",
        "true",
        "error",
    ]
    assert "1% disagreement in brightness between the target (rendered by mitsuba) and warp-hair" in table
    plain = types.SimpleNamespace(
        values=fit_result.values,
        uncertainties=result.parts["noise"],
        uncertainty_parts={**result.parts, "model_error": 0.0},
    )
    assert "± model" not in format_table(plain, {})


@pytest.mark.parametrize("value", [-0.01, float("nan"), float("inf"), "1%", True])
def test_bad_model_errors_are_refused(own_target, value):
    target = load_target(own_target)
    with pytest.raises(ValueError, match=r"model_error must be a finite number >= 0 \(a relative brightness"):
        check_settings(target, FitSettings(model_error=value))


@pytest.mark.parametrize("text", ["-0.01", "nan", "inf"])
def test_the_commands_refuse_bad_model_errors(own_target, tmp_path, capsys, text):
    for command in (
        ["fit", str(own_target), "-o", str(tmp_path / "out"), "--iters", "1"],
        ["targets", "check", str(own_target)],
    ):
        assert main([*command, "--model-error", text]) == 2
        assert (
            f"--model-error must be a finite number >= 0 (a relative brightness disagreement, e.g. 0.01 for 1%; 0 "
            f"for none), got {float(text)!r}" in capsys.readouterr().err
        )
    assert not (tmp_path / "out").exists()


def test_the_default_model_error_follows_who_rendered_the_target(own_target, tmp_path):
    """0 for warp-hair's own images, 1% for a peer's (target.toml says so) or for images whose headers do not
    say warp-hair made them (a photograph, an EXR from elsewhere)."""
    own = load_target(own_target)
    assert own.origin == "warp-hair" and target_model_error(own) == 0.0
    assert target_model_error(own, 0.003) == 0.003
    for spec, origin in (('renderer = "mitsuba"\n', "mitsuba"), ("", "unknown")):
        copy_dir = tmp_path / origin
        copy_dir.mkdir()
        for name in ("front", "back"):
            (copy_dir / f"scene_{name}.toml").write_text((own_target / f"scene_{name}.toml").read_text())
            write_exr(copy_dir / f"{name}.exr", next(im.image for im in own.images if im.name == name))
        (copy_dir / "target.toml").write_text(spec + (own_target / "target.toml").read_text())
        other = load_target(copy_dir)
        assert other.origin == origin and target_model_error(other) == PEER_MODEL_ERROR


def test_params_json_holds_the_parts(tmp_path):
    rng = np.random.default_rng(14)
    result = _estimated(_linearization(rng), 0.01, None)
    fit_result = types.SimpleNamespace(
        target="t",
        values={"beta_m": 0.31, "beta_n": 0.39},
        start={},
        loss=0.1,
        uncertainties=result.uncertainties,
        uncertainty_parts=result.parts,
        iterations=1,
        history=types.SimpleNamespace(refine=()),
        stop_reason="iterations",
        seconds=1.0,
        warnings=[],
        correlations={},
        goodness=None,
        failed=False,
        failures=[],
    )
    look = types.SimpleNamespace(to_dict=dict)
    write_params(tmp_path / "params.json", fit_result, {}, look)
    data = json.loads((tmp_path / "params.json").read_text())
    parts = data["uncertainty_parts"]
    assert parts["model_error"] == 0.01
    for name in ("beta_m", "beta_n"):
        assert data["uncertainty"][name] == pytest.approx(np.hypot(parts["noise"][name], parts["model"][name]))
