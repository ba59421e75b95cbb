"""Hair as it grows (model/variation.py): each strand's look, the root-to-tip ramp, and their derivatives.

The derivative check renders paths of one bounce lit by a directional light: a path is then the camera ray's hit
and its light sample, neither drawn from the BSDF, so with the same seed a render is a smooth function of the
controls and central differences check every column of the Jacobian pixel by pixel, not only in expectation.
"""

import numpy as np
import pytest
from helpers.scenes import front_camera

from warp_hair.controls import CONTROLS, controls_of
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.model.variation import (
    CYCLES_MELANIN_UNITS,
    MELANIN_CLAMP,
    has_variation,
    melanin_factor,
    strand_looks,
    strand_random,
)
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

VARIATION = {"color_spread": 0.4, "roughness_spread": 0.3, "tip_absorption": 0.35, "tip_length": 0.6}
COLOURS = {
    "albedo": {"albedo": [0.55, 0.35, 0.2]},
    "sigma_a": {"sigma_a": [0.3, 0.6, 1.1]},
    "melanin": {"eumelanin": 1.3, "pheomelanin": 0.4},
}
LIGHT = [{"type": "directional", "direction": [0.2, -0.3, -1.0], "irradiance": [3.0, 3.0, 3.0]}]


def _scene(hair, max_depth=1, fibers=None, resolution=(16, 16)):
    return scene_from_dict(
        {
            "camera": front_camera(0.3, resolution),
            "lights": LIGHT,
            "fibers": fibers or {"generator": "swatch", "count": 60, "layers": 2, "length": 0.6, "seed": 3},
            "hair": {"beta_m": 0.3, "beta_n": 0.35, "alpha": 2.0, **hair},
            "render": {"spp": 4, "max_depth": max_depth, "seed": 2},
        }
    )


def _moved(hair, name, component, step):
    value = getattr(hair, name)
    if CONTROLS[name].size == 3:
        value = list(value)
        value[component] += step
    else:
        value = value + step
    changes = {name: value}
    if hair.colour_input == "melanin":  # replace() would drop the other pigment
        changes = {"eumelanin": hair.eumelanin, "pheomelanin": hair.pheomelanin, **changes}
    return hair.replace(**changes)


@pytest.mark.parametrize("colour_input", list(COLOURS))
def test_every_column_matches_central_differences_pixel_by_pixel(colour_input):
    scene = _scene({**COLOURS[colour_input], **VARIATION})
    prepared = prepare(scene)
    jacobian, image, _ = render_jacobian(prepared, spp=4, seed=5)
    assert image.max() > 0.01
    for name in controls_of(colour_input):
        control = CONTROLS[name]
        step = 0.02 * control.gradcheck_step
        for component, column in enumerate(control.columns):
            plus = render(prepared.with_hair(_moved(scene.hair, name, component, step)), spp=4, seed=5)
            minus = render(prepared.with_hair(_moved(scene.hair, name, component, -step)), spp=4, seed=5)
            difference = (plus - minus) / (2.0 * step)
            analytic = jacobian[..., column]
            scale = max(np.abs(difference).max(), 1e-6)
            # Pixels whose hits sit at a clamp's kink (the melanin clamp, a ramp's ends) differ; all others agree.
            close = np.abs(analytic - difference) <= 0.01 * scale
            assert close.mean() > 0.97, (name, component, close.mean())
            assert abs(analytic.sum() - difference.sum()) <= 0.01 * np.abs(difference).sum() + 1e-6, name


@pytest.mark.parametrize("colour_input", list(COLOURS))
def test_the_variation_has_its_gradient_at_no_variation(colour_input):
    """At the defaults (spreads 0, tip factor 1), where a fit of lighter tips starts, each strand's first-order
    change is there: one-sided differences for the spreads (they cannot go below 0), central for the tip."""
    scene = _scene(COLOURS[colour_input])
    prepared = prepare(scene)
    jacobian, _, _ = render_jacobian(prepared, spp=4, seed=5)
    base = render(prepared, spp=4, seed=5)
    for name, step, central in (
        ("color_spread", 1e-3, False),
        ("roughness_spread", 1e-3, False),
        ("tip_absorption", 1e-3, True),
    ):
        plus = render(prepared.with_hair(_moved(scene.hair, name, 0, step)), spp=4, seed=5)
        if central:
            minus = render(prepared.with_hair(_moved(scene.hair, name, 0, -step)), spp=4, seed=5)
            difference = (plus - minus) / (2.0 * step)
        else:
            difference = (plus - base) / step
        analytic = jacobian[..., CONTROLS[name].columns[0]]
        scale = np.abs(difference).max()
        assert scale > 1e-3, name  # not 0: each strand's image moves, though their mean hardly does
        close = np.abs(analytic - difference) <= 0.02 * scale
        assert close.mean() > 0.97, (name, close.mean())


def test_a_look_without_variation_has_no_per_strand_data():
    """The default of every variation control is no variation: the kernels then read the material's coefficients
    as before (renders, and the other controls' gradients, bit for bit as without the variation's controls)."""
    hair = _scene(COLOURS["albedo"]).hair
    assert not has_variation(hair)
    variation = prepare(_scene(COLOURS["albedo"])).data.variation
    assert variation.strands == 0 and variation.tip == 0
    assert has_variation(hair.replace(tip_absorption=0.5))
    assert not has_variation(hair.replace(tip_length=0.2))  # where the ramp runs changes nothing at factor 1


def _one_strand(hair):
    return _scene(hair, max_depth=8, fibers={"generator": "swatch", "count": 1, "layers": 1, "length": 0.6})


@pytest.mark.parametrize("colour_input", ["albedo", "sigma_a"])
def test_a_strand_renders_as_the_uniform_look_of_its_factors(colour_input):
    """Cycles' Random Roughness and (on σ_a) our colour spread: β·(1 + 2(u − ½)r), σ_a·(1 + 2(u − ½)c)."""
    spread = {"color_spread": 0.5, "roughness_spread": 0.4}
    varied = _one_strand({**COLOURS[colour_input], **spread})
    (u,) = strand_random(1).astype(np.float64)
    f_c = 1.0 + 2.0 * (u - 0.5) * 0.5
    f_r = 1.0 + 2.0 * (u - 0.5) * 0.4
    hair = varied.hair
    absorption = np.asarray(hair.replace(beta_n=hair.beta_n * f_r, color_spread=0.0).absorption) * f_c
    uniform = _one_strand({"sigma_a": list(absorption), "beta_m": hair.beta_m * f_r, "beta_n": hair.beta_n * f_r})
    uniform = prepare(uniform).with_hair(
        uniform.hair.replace(beta_m=hair.beta_m * f_r, beta_n=hair.beta_n * f_r, alpha=hair.alpha)
    )
    a, b = render(varied, spp=16, seed=3), render(uniform, spp=16, seed=3)
    assert a.max() > 0.01
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-7)


def test_melanin_spread_is_cycles_random_color():
    """Cycles 4.5 (svm/closure.h): melanin m ∈ [0, 1] is scaled by the strand's factor, then −ln(max(1 − m, 1e−4))
    is the concentration in its own units, split by the redness; restated here in float64 for many factors."""
    eumelanin, pheomelanin = 1.3, 0.4
    total = eumelanin / CYCLES_MELANIN_UNITS[0] + pheomelanin / CYCLES_MELANIN_UNITS[1]
    m = 1.0 - np.exp(-total)  # the Melanin input that gives this concentration
    factors = np.linspace(0.5, 1.5, 41)
    strand_total = -np.log(np.maximum(1.0 - factors * m, MELANIN_CLAMP))
    k, _, _ = melanin_factor(total, factors)
    np.testing.assert_allclose(k * total, strand_total, rtol=1e-12)
    assert (strand_total == -np.log(MELANIN_CLAMP)).any(), "the factors should reach Cycles' clamp"


def test_melanin_factor_derivatives_are_those_of_the_mapping():
    total = np.array([0.05, 0.7, 1.6, 3.0])
    f = np.array([0.7, 1.1, 0.9, 1.05])
    _, dk_dtotal, dk_df = melanin_factor(total, f)
    h = 1e-6

    def k(total, f):
        return melanin_factor(total, f)[0]

    np.testing.assert_allclose(dk_dtotal, (k(total + h, f) - k(total - h, f)) / (2 * h), rtol=1e-6)
    np.testing.assert_allclose(dk_df, (k(total, f + h) - k(total, f - h)) / (2 * h), rtol=1e-6)


def test_strand_looks_spread_about_the_look():
    """Over many strands the factors are uniform in [1 − s, 1 + s]: their mean is the look's own value."""
    hair = _scene({**COLOURS["sigma_a"], "color_spread": 0.5, "roughness_spread": 0.2}).hair
    u = strand_random(20000)
    assert 0.0 <= u.min() and u.max() <= 1.0
    looks = strand_looks(hair, u)
    np.testing.assert_allclose(looks.sigma_a.mean(axis=0), hair.sigma_a, rtol=0.01)
    np.testing.assert_allclose(looks.beta_m.mean(), hair.beta_m, rtol=0.005)
    assert looks.beta_m.min() == pytest.approx(0.3 * 0.8, rel=1e-3)
    assert looks.beta_m.max() == pytest.approx(0.3 * 1.2, rel=1e-3)


def test_arc_fractions_run_root_to_tip_by_length():
    points = np.array([[[0, 0, 0], [0, 1, 0], [0, 4, 0]], [[1, 0, 0], [1, 0, 2], [1, 0, 3]]], dtype=np.float32)
    start, span = FiberAssembly.from_arrays(points, 0.01).segment_arc_fractions()
    np.testing.assert_allclose(start, [0.0, 0.25, 0.0, 2 / 3])
    np.testing.assert_allclose(span, [0.25, 0.75, 2 / 3, 1 / 3])


def test_a_varied_render_does_not_depend_on_the_threads():
    scene = _scene({**COLOURS["melanin"], **VARIATION}, max_depth=8)
    np.testing.assert_array_equal(render(scene, spp=4, seed=1, threads=1), render(scene, spp=4, seed=1, threads=2))


def test_a_usd_random_primvar_gives_each_strand_its_value(tmp_path):
    """A groom's own per-curve `random` primvar replaces the index-drawn values: the index's own values written
    as the primvar render the same image, other values another."""
    pytest.importorskip("pxr", reason="usd-core is the `usd` extra")
    from warp_hair.geometry import save_fibers

    hair = {**COLOURS["albedo"], "color_spread": 0.5, "roughness_spread": 0.3}
    scene = _scene(hair)
    fibers = scene.fibers
    drawn = strand_random(fibers.num_strands)
    for name, values in (("same", drawn), ("reversed", drawn[::-1])):
        with_random = FiberAssembly(fibers.points, fibers.radii, fibers.strand_offsets, strand_random=values)
        save_fibers(with_random, tmp_path / f"{name}.usda")
    same = _scene(hair, fibers={"file": str(tmp_path / "same.usda")})
    np.testing.assert_array_equal(same.fibers.strand_random, drawn)
    reference = render(scene, spp=4, seed=1)
    np.testing.assert_array_equal(render(same, spp=4, seed=1), reference)
    other = render(_scene(hair, fibers={"file": str(tmp_path / "reversed.usda")}), spp=4, seed=1)
    assert np.abs(other - reference).max() > 1e-3


def test_random_values_outside_the_unit_interval_are_refused():
    points = np.zeros((2, 2, 3), dtype=np.float32)
    points[:, 1, 1] = 1.0
    fibers = FiberAssembly.from_arrays(points, 0.01)
    with pytest.raises(ValueError, match=r"strand 1: random value 1.5 is outside \[0, 1\]"):
        FiberAssembly(fibers.points, fibers.radii, fibers.strand_offsets, strand_random=[0.2, 1.5])
    with pytest.raises(ValueError, match="one value per strand"):
        FiberAssembly(fibers.points, fibers.radii, fibers.strand_offsets, strand_random=[0.2])


def test_a_random_seed_redraws_the_strands_values():
    hair = {**COLOURS["albedo"], "color_spread": 0.5}
    fibers = {"generator": "swatch", "count": 60, "layers": 2, "length": 0.6, "seed": 3}
    default, seeded = _scene(hair), _scene(hair, fibers={**fibers, "random_seed": 7})
    np.testing.assert_array_equal(seeded.fibers.strand_random, strand_random(60, 7))
    assert np.abs(render(seeded, spp=4, seed=1) - render(default, spp=4, seed=1)).max() > 1e-3
    np.testing.assert_array_equal(
        render(_scene(hair, fibers={**fibers, "random_seed": 0}), spp=4, seed=1), render(default, spp=4, seed=1)
    )
    with pytest.raises(ValueError, match="random_seed"):
        _scene(hair, fibers={**fibers, "random_seed": -1})
