"""benchmarks/fit_wall_time.py (issue 45's goal 2): it runs the fit as the `warp-hair` command does, exit status
included, and reads a fit's result from its params.json."""

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fit_wall_time():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        return importlib.import_module("fit_wall_time")
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))


def test_the_fit_it_runs_exits_as_the_command_does(fit_wall_time, tmp_path):
    """A fit that fails must not pass for a timed one: its process exits with the CLI's status (here 2, an unknown
    target), not 0 as `main()` alone would leave it."""
    done = subprocess.run(
        [sys.executable, "-c", fit_wall_time.RUN_FIT, "fit", "no_such_target", "-o", str(tmp_path / "out")],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2, done.stderr
    assert "no_such_target" in done.stderr


def test_summary_reads_the_largest_error_over_sigma(fit_wall_time):
    params = {
        "error": {"albedo": [0.01, -0.03, 0.0], "beta_m": 0.002},
        "uncertainty": {"albedo": [0.01, 0.01, 0.01], "beta_m": 0.004},
        "gauss_newton_steps": [{}, {}, {}],
        "seconds": 12.5,
    }
    assert fit_wall_time.summary(params) == {"steps": 3, "seconds": 12.5, "worst": 3.0}
    # A target without a truth (a photograph) has no error to weigh.
    assert fit_wall_time.summary({"gauss_newton_steps": [], "seconds": 1.0})["worst"] is None
