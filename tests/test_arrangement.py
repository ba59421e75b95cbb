"""How the strands lie, as unknowns of the fit (optimize/arrangement.py): the prior in target.toml, its draws, the
common-random-number columns and the fit's estimate."""

import json

import numpy as np
import pytest
from helpers.scenes import front_camera, toml_text, write_front_back_target

from optimize.arrangement import Arrangement, columns, photo_defaults
from optimize.fit import fit
from optimize.realisations import Realisations
from optimize.settings import FitSettings
from optimize.target import load_target, make_target
from warp_hair.realisation import realisation
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

HAIR = {"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.35}


def _scene_text(direction, generator="swatch"):
    return toml_text(
        {
            "camera": front_camera(0.2, (8, 8)),
            "lights": [{"type": "directional", "direction": direction, "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {
                "generator": generator,
                "count": 30,
                "layers": 2,
                "length": 0.3,
                "width": 0.24,
                "drape": 0.2,
                **({"amplitude": 0.01, "wavelength": 0.1} if generator == "wavy" else {}),
            },
            "hair": HAIR,
            "render": {"spp": 8, "max_depth": 8, "seed": 2},
        }
    )


def _target(tmp_path, table: str, realisations='realisations = "random"\n', generator="swatch"):
    directory = write_front_back_target(tmp_path, lambda direction: _scene_text(direction, generator))
    make_target(directory)
    spec = directory / "target.toml"
    spec.write_text(realisations + spec.read_text() + table)
    return directory


@pytest.mark.parametrize(
    "table, message",
    [
        ("[arrangement]\nclump = [0, 1]\n", r"\[arrangement\] unknown key\(s\) \['clump'\]; allowed: \['jitter'"),
        ("[arrangement]\njitter = [0.1, 0.6]\n", r"jitter = \[0.1, 0.6\]: outside the generator's allowed values"),
        ("[arrangement]\njitter = 0.2\n", r"jitter must be a range \[low, high\] of two numbers, got 0.2"),
        ("[arrangement]\njitter = [0.3, 0.1]\n", r"jitter = \[0.3, 0.1\]: needs finite low <= high"),
        ("[arrangement]\nlayer_gap = [0.0, 0.01]\n", r"layer_gap = \[0.0, 0.01\]: outside .*positive"),
        ("[arrangement]\nlayers = [1, 40]\n", r"layers = \[1, 40\]: at most the count \(30\)"),
        ("[arrangement]\nlayers = [1.0, 3.0]\n", r"layers must be a range of integers"),
        ("[arrangement]\nphase_jitter = [0, 1]\n", r"generator 'swatch' does not take phase_jitter"),
        ("[arrangement]\nclump_strength = [0.2, 1.2]\n", r"clump_strength = \[0.2, 1.2\]: outside .*within \[0, 1\]"),
        # A swatch without clumps has no strength to vary: the generator's rule, at a corner.
        ("[arrangement]\nclump_strength = [0.2, 0.6]\n", r"the generator says: clump_strength needs clumps"),
        # Twelve layers 0.02 apart are deeper than the drape's radius (0.2): the generator's rule, at a corner.
        ("[arrangement]\nlayers = [2, 12]\nlayer_gap = [0.01, 0.02]\n", r"at \{.*\}: the generator says: drape"),
    ],
)
def test_a_bad_prior_names_the_key_and_what_is_allowed(tmp_path, table, message):
    directory = _target(tmp_path, table)
    with pytest.raises(ValueError, match=message):
        load_target(directory)


def test_a_prior_needs_random_realisations(tmp_path):
    directory = _target(tmp_path, "[arrangement]\njitter = [0.1, 0.3]\n", realisations="")
    with pytest.raises(
        ValueError, match=r'\[arrangement\] is a prior over the realisations .* realisations = "random"'
    ):
        load_target(directory)


def test_draws_are_deterministic_within_the_prior_and_both_views_share_them(tmp_path):
    table = "[arrangement]\njitter = [0.05, 0.35]\nlayer_gap = [0.009, 0.012]\nlayers = [1, 3]\n"
    target = load_target(_target(tmp_path, table))
    prior = target.arrangement
    assert prior.continuous == ["jitter", "layer_gap"]
    draws = [prior.draw(0, k) for k in range(1, 200)]  # the scenes' [fibers] seed: 0, the default
    assert draws == [prior.draw(0, k) for k in range(1, 200)]
    assert draws != [prior.draw(1, k) for k in range(1, 200)]
    for key, (low, high) in prior.ranges.items():
        values = np.array([d[key] for d in draws])
        assert low <= values.min() and values.max() <= high
        assert values.max() - values.min() > 0.8 * (high - low)  # they fill the range
    assert {d["layers"] for d in draws} == {1, 2, 3}
    # The fit's realisations take them: realisation k is the recipe with draw k, the same strands in both views.
    pool = Realisations(target, pool=3)
    for k in (1, 2):
        scenes = pool.scenes(k)
        expected = realisation(target.images[0].scene, k, draws[k - 1])
        np.testing.assert_array_equal(scenes[0].scene.fibers.points, expected.fibers.points)
        np.testing.assert_array_equal(scenes[1].scene.fibers.points, scenes[0].scene.fibers.points)


def test_without_a_prior_the_realisations_are_as_before(tmp_path):
    """A target without [arrangement] draws exactly the realisations it drew: the recipe untouched."""
    target = load_target(_target(tmp_path, ""))
    assert target.arrangement is None
    pool = Realisations(target, pool=3)
    for k in (1, 3):
        before = realisation(target.images[0].scene, k)
        np.testing.assert_array_equal(pool.scenes(k)[0].scene.fibers.points, before.fibers.points)
    assert realisation(target.images[0].scene, 0) is target.images[0].scene


# The variance ratio per pixel, independent over common numbers, at least: measured 3.1 for jitter, 2.1 for the
# layers' shift, whose strands that wrap from one edge of the swatch to the other jump whatever the numbers.
@pytest.mark.parametrize(
    "key, middle, step, gain", [("jitter", 0.2, 0.05, 2.0), ("layer_shift_jitter", 0.5, 0.125, 1.5)]
)
def test_common_random_numbers_give_the_realisation_averages_difference_with_less_variance(key, middle, step, gain):
    """(I_k(θ + δ) − I_k(θ − δ)) / 2δ with the same strands' draws and render seed, averaged over realisations k,
    estimates the difference quotient of the realisation average (exactly, by linearity: arrangement.py): here it
    agrees with the difference of two independently estimated realisation means, with less variance per pixel."""
    scene = scene_from_dict(
        {
            "camera": front_camera(0.2, (16, 16)),
            "lights": [{"type": "directional", "direction": [0.0, -0.15, 1.0], "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {"generator": "swatch", "count": 24, "layers": 2, "length": 0.3, "width": 0.24, "drape": 0.2},
            "hair": HAIR,
            "render": {"spp": 4, "max_depth": 6, "seed": 2},
        }
    )
    draws = 40

    def image(k, value, seed):
        return render(realisation(scene, k, {key: value}), spp=4, seed=seed).mean(axis=-1)

    crn = np.array(
        [(image(k, middle + step, k) - image(k, middle - step, k)) / (2 * step) for k in range(1, draws + 1)]
    )
    # Independent: other realisations and render seeds for the + and − renders.
    independent = np.array(
        [
            (image(k, middle + step, k) - image(k + 500, middle - step, k + 900)) / (2 * step)
            for k in range(1001, 1001 + draws)
        ]
    )
    for quotients in (crn, independent):  # the whole image's mean: one number per draw
        assert np.isfinite(quotients).all()
    means = crn.mean(axis=(1, 2)), independent.mean(axis=(1, 2))
    se = [m.std(ddof=1) / np.sqrt(draws) for m in means]
    assert abs(means[0].mean() - means[1].mean()) < 3 * np.hypot(*se)
    # Per pixel, the common numbers' quotient varies less (the gain grows as δ shrinks).
    assert independent.var(axis=0, ddof=1).mean() > gain * crn.var(axis=0, ddof=1).mean()


def test_columns_follow_the_prior_and_a_fit_reports_the_arrangement(tmp_path):
    table = "[arrangement]\njitter = [0.05, 0.35]\nlayers = [2, 3]\n"
    target = load_target(_target(tmp_path, table))
    prior = target.arrangement
    settings = FitSettings()
    middles, crn = columns(target, prior, {"beta_n": 0.35}, ["jitter"], 2, 2, 5, settings)
    assert middles.shape[0] == 2 and crn.shape == (2, middles.shape[1], 1)
    result = fit(target, progress=False, iters=3, spp=2, refine=1, realisation_samples=3, batch=None)
    found = result.arrangement
    assert list(found["estimate"]) == ["jitter"]  # layers is marginalised only
    entry = found["estimate"]["jitter"]
    assert np.isfinite(entry["value"]) and entry["sigma"] > 0 and entry["prior"] == [0.05, 0.35]
    assert set(found["look_share_of_variance"]) == {"albedo[r]", "albedo[g]", "albedo[b]", "beta_m", "beta_n"}
    assert all(v >= 0 for v in found["look_share_of_variance"].values())
    assert isinstance(found["look_at_estimate_outside"], list)
    json.dumps(found)  # params.json can hold it


def test_a_look_the_linear_step_takes_outside_the_controls_ranges_is_named():
    """One linear step from the prior's middle can land on an albedo below 0 (a photo of Blender's straight
    swatch did): the record names those components, and the report prints no look there."""
    from optimize.arrangement import _outside_ranges

    labels = ["albedo[r]", "albedo[g]", "albedo[b]", "beta_m", "beta_n"]
    assert _outside_ranges({"albedo": [-0.04, 0.01, 1.2], "beta_m": 0.3, "beta_n": 0.4}, labels) == [
        "albedo[r]",
        "albedo[b]",
    ]
    assert _outside_ranges({"albedo": [0.3, 0.2, 0.1], "beta_m": 0.3, "beta_n": 0.4}, labels) == []


def test_photo_defaults_state_what_a_photographer_cannot_measure():
    assert photo_defaults({"generator": "swatch", "radius": 0.004}) == {
        "jitter": [0.05, 0.4],
        "layer_gap": [0.008, 0.015],
        "layer_shift_jitter": [0.0, 1.0],
    }
    # With clumps, how far they close, as read off the tips: the recipe's strength ± 0.2 within [0, 1].
    clumped = {"generator": "wavy", "radius": 0.004, "clumps": 10, "clump_strength": 0.9}
    assert photo_defaults(clumped)["clump_strength"] == [0.7, 1.0]
    assert photo_defaults({**clumped, "clump_strength": 0.6})["clump_strength"] == [0.4, 0.8]
    assert "clump_strength" not in photo_defaults({"generator": "swatch", "radius": 0.004, "clumps": 0})
    assert photo_defaults({"generator": "fur", "root_radius": 0.001}) == {}
    assert Arrangement({"jitter": (0.1, 0.1)}).continuous == []  # a point is fixed, not estimated
