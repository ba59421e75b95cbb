"""benchmarks/equal_quality.py's measure of noise (issue 45): what its docstring defines is what it computes."""

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def modules():
    """(equal_quality, mitsuba_peer): the benchmark scripts import each other by name from their folder."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return importlib.import_module("equal_quality"), importlib.import_module("mitsuba_peer")
    finally:
        sys.path.remove(str(BENCHMARKS))


def noisy(truth, sigma, rng):
    return truth + rng.normal(0.0, 1.0, truth.shape) * sigma


def test_relative_mse_takes_out_the_references_own_noise(modules):
    """Images of a known truth with known noise: the relative MSE is the image's own variance over the mean squared,
    whatever noise the reference's halves carry (here as much as the image's, which would add half of it)."""
    equal_quality, _ = modules
    rng = np.random.default_rng(4)
    truth = rng.uniform(0.5, 1.5, (256, 256, 3)) * np.array([1.0, 0.7, 0.4])
    sigma = 0.2 * truth  # noise that varies over the image, as a render's does
    image = noisy(truth, sigma, rng)
    halves = (noisy(truth, sigma, rng), noisy(truth, sigma, rng))
    expected = np.mean(np.mean(sigma**2, axis=(0, 1)) / truth.mean(axis=(0, 1)) ** 2)
    mse, own = equal_quality.relative_mse(image, halves)
    assert mse == pytest.approx(expected, rel=0.02)
    assert own == pytest.approx(expected / 2, rel=0.02)  # the 2-half reference's own noise, estimated
    # Exposure-free: the same images at another scale give the same figures.
    assert equal_quality.relative_mse(3.0 * image, tuple(3.0 * h for h in halves)) == pytest.approx((mse, own))


def test_mitsuba_scene_names_the_sensor_samplers_it_takes(modules):
    _, mitsuba_peer = modules
    with pytest.raises(ValueError, match=r"sensor_sampler must be one of .*'multijitter'.*not 'stratified'"):
        mitsuba_peer.mitsuba_scene(None, None, 4, sensor_sampler="stratified")
