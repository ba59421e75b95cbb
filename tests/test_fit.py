"""A real, reduced fit: render a small target with known controls, forget them, recover them by gradient descent.

The target is a 24×24 draped swatch under a front and a back light, rendered here at high spp; the fit starts
from the neutral guess (albedo 0.5 grey, β_m = β_n = 0.5) and runs the same code as `warp-hair fit`, with fewer
iterations and samples than the shipped targets use.
"""

import json

import numpy as np
import pytest
from helpers.scenes import draped_swatch_text, write_front_back_target

from optimize.cli import main
from optimize.fit import fit
from optimize.target import load_target, make_target
from warp_hair.controls import controls_of

TRUTH = {"albedo": [0.55, 0.38, 0.22], "beta_m": 0.3, "beta_n": 0.4}


def scene_text(direction, spp):
    """A 120-fiber draped swatch with the TRUTH controls under one directional light, 24×24 pixels."""
    return draped_swatch_text(direction, TRUTH, spp, "fit")


# At 1024 spp this target's own noise leaves red albedo uncertain by ±0.03 (1σ, as the fit reports it), the
# bound below: the fit passed or failed by chance. At 4096, ±0.012.
TARGET_SPP = 4096


@pytest.fixture(scope="module")
def small_target(tmp_path_factory):
    directory = write_front_back_target(
        tmp_path_factory.mktemp("small_target"), lambda direction: scene_text(direction, TARGET_SPP)
    )
    make_target(directory)
    return directory


def test_fit_rejects_an_unknown_export_before_fitting(small_target, tmp_path, capsys):
    assert main(["fit", str(small_target), "-o", str(tmp_path / "o"), "--export", "mitsuba,arnold"]) == 2
    assert "unknown renderer 'arnold'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("batch", [None, 144], ids=["whole", "mini-batch"])
def test_reduced_fit_recovers_the_true_controls(small_target, batch):
    """With `batch` 144 each iteration renders 9 of the 36 4×4 blocks of the 24×24 images, and the
    Gauss–Newton passes all pixels at a quarter of the samples: the same bounds must hold."""
    target = load_target(small_target)
    result = fit(target, iters=80, spp=16, pool=4, progress=False, batch=batch)
    assert not result.failed, result.failures  # a fit that finds its look does not call itself failed
    assert result.iterations >= 40
    albedo_error = np.abs(np.subtract(result.values["albedo"], TRUTH["albedo"]))
    assert albedo_error.max() < 0.03, result.values
    assert abs(result.values["beta_m"] - TRUTH["beta_m"]) < 0.04, result.values
    assert abs(result.values["beta_n"] - TRUTH["beta_n"]) < 0.04, result.values
    # The uncertainties are finite, positive, and the truth lies within four of them (they count the target's
    # noise and the estimate's own Monte Carlo error; the Jacobian's noise once made them ten times too small).
    for name, value in result.values.items():
        sigma = np.atleast_1d(result.uncertainties[name])
        assert np.all(sigma > 0) and np.all(np.isfinite(sigma))
        error = np.abs(np.atleast_1d(value) - np.atleast_1d(TRUTH[name]))
        assert np.all(error < 4 * sigma), (name, error, sigma)
    # From the neutral guess the loss must have come down by a large factor.
    assert np.mean(result.history.loss[-10:]) < 0.5 * np.mean(result.history.loss[:5])


def test_fit_command_writes_its_outputs(small_target, tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(
            [
                "fit",
                str(small_target),
                "-o",
                str(out),
                "--iters",
                "6",
                "--spp",
                "4",
                "--fit",
                "albedo,beta_m",
                "--export",
                "mitsuba,cycles",
                # Six iterations find no look from the neutral guess, and such a fit says it failed (status 3).
                "--init",
                f"albedo={','.join(map(str, TRUTH['albedo']))}",
                f"beta_m={TRUTH['beta_m']}",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "fitted" in printed and "true" in printed and "beta_m" in printed
    params = json.loads((out / "params.json").read_text())
    assert set(params["fitted"]) == {"albedo", "beta_m"}
    # The look: the fitted controls and the scenes' fixed ones, every control of the hair.
    look = params["look"]
    assert set(look) == set(controls_of("albedo"))
    assert look["albedo"] == params["fitted"]["albedo"] and look["beta_m"] == params["fitted"]["beta_m"]
    assert all(look[name] == TRUTH[name] for name in TRUTH if name not in params["fitted"])
    assert "longitudinal_roughness" in (out / "hair_mitsuba.xml").read_text()
    assert "ShaderNodeBsdfHairPrincipled" in (out / "hair_cycles.py").read_text()
    assert params["true"]["beta_m"] == TRUTH["beta_m"] and len(params["error"]["albedo"]) == 3
    assert params["iterations"] == 6 and np.isfinite(params["loss"])
    for picture in ("convergence.png", "comparison.png"):
        assert (out / picture).stat().st_size > 10_000
