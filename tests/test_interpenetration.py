"""Strands that pass through each other: the scene check (warp_hair.geometry.interpenetration) and the two rules
for a ray that starts inside another strand's tube (warp_hair.geometry.intersect, `[render] interpenetration`)."""

import warnings

import numpy as np
import pytest

from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.generators import wavy
from warp_hair.geometry.interpenetration import (
    InterpenetrationWarning,
    interpenetration,
    points_inside_other_strands,
    warn_interpenetration,
)
from warp_hair.geometry.rays import intersect, occluded
from warp_hair.geometry.tubes import FiberBVH
from warp_hair.scene import scene_from_dict

R = 0.01


def two_strands(first, second, radius=R):
    return FiberAssembly.from_strands([(np.asarray(first), radius), (np.asarray(second), radius)])


# --- the check ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("gap", [1.5, 1.999, 2.001, 3.0])
def test_parallel_strands_overlap_exactly_when_closer_than_two_radii(gap):
    strands = two_strands([[0, -1, 0], [0, 0, 0], [0, 1, 0]], [[gap * R, -1, 0], [gap * R, 1, 0]])
    report = interpenetration(strands)
    assert report.pairs == (1 if gap < 2 else 0)
    assert report.strands == (2 if gap < 2 else 0)
    assert report.deepest == pytest.approx(max(0.0, 1 - gap / 2), abs=1e-5)


def test_crossing_axes_overlap_completely_and_a_strand_never_overlaps_itself():
    # Two straight strands whose axes cross, and a third that folds back on itself within one radius.
    cross = two_strands([[-1, 0, 0], [1, 0, 0]], [[0, -1, 0], [0, 1, 0]])
    report = interpenetration(cross)
    assert (report.pairs, report.segment_pairs) == (1, 1)
    assert report.deepest == pytest.approx(1.0, abs=1e-6)
    hairpin = FiberAssembly.from_strands([(np.array([[0, 0, 5], [1, 0, 5], [1, 0.5 * R, 5], [0, 0.5 * R, 5]]), R)])
    assert interpenetration(hairpin).pairs == 0


def segment_distances(p0, p1, q0, q1):
    """float64 distance between every segment of (p0, p1) and every one of (q0, q1), by minimising over a dense
    parameter grid and then over each clamped edge exactly (the minimum of a convex quadratic on a square)."""
    s = np.linspace(0, 1, 201)
    d1, d2 = p1 - p0, q1 - q0
    best = np.full((len(p0), len(q0)), np.inf)
    for fixed_s in (False, True):
        # Minimise over t for each s on the grid (or s for each t), clamped: exact on that line.
        for value in s:
            if fixed_s:
                a = p0 + value * d1
                t = np.einsum("jk,ijk->ij", d2, a[:, None, :] - q0[None]) / np.einsum("jk,jk->j", d2, d2)
                t = np.clip(t, 0, 1)
                gap = a[:, None, :] - (q0[None] + t[..., None] * d2[None])
            else:
                b = q0 + value * d2
                u = np.einsum("ik,ijk->ij", d1, b[None, :, :] - p0[:, None]) / np.einsum("ik,ik->i", d1, d1)[:, None]
                u = np.clip(u, 0, 1)
                gap = (p0[:, None] + u[..., None] * d1[:, None]) - b[None]
            best = np.minimum(best, np.linalg.norm(gap, axis=-1))
    return best


def test_a_wavy_swatch_agrees_with_a_float64_brute_force():
    fibers = wavy(
        count=12,
        layers=2,
        length=0.2,
        radius=0.004,
        width=0.05,
        amplitude=0.006,
        wavelength=0.08,
        phase_jitter=1.0,
        segments=12,
        seed=3,
    )
    p0, p1, r0, r1, strand, _ = fibers.segments()
    p0, p1 = p0.astype(np.float64), p1.astype(np.float64)
    distance = segment_distances(p0, p1, p0, p1)
    reach = (r0 + r1)[:, None] / 2 + (r0 + r1)[None, :] / 2
    other = strand[:, None] != strand[None, :]
    ratio = np.where(other, distance / reach, np.inf)
    # No pair within rounding of the threshold, so that the count is not decided by float32.
    assert not np.any(np.abs(ratio - 1) < 1e-4)
    i, j = np.nonzero(np.triu(ratio < 1))
    expected = {(min(a, b), max(a, b)) for a, b in zip(strand[i], strand[j])}
    report = interpenetration(fibers)
    assert report.pairs == len(expected) > 3
    assert report.segment_pairs == len(i)
    assert report.strands == len({s for pair in expected for s in pair})
    assert report.deepest == pytest.approx(1 - ratio.min(), abs=1e-4)


def test_loading_an_interpenetrating_scene_warns_once_and_names_the_rule():
    data = {
        "camera": {
            "type": "orthographic",
            "origin": [0, 0, 3],
            "target": [0, 0, 0],
            "up": [0, 1, 0],
            "width": 0.3,
            "resolution": [8, 8],
        },
        "lights": [{"type": "directional", "direction": [0, 0, -1], "irradiance": [1, 1, 1]}],
        "fibers": {
            "generator": "wavy",
            "count": 12,
            "layers": 2,
            "length": 0.2,
            "width": 0.05,
            "amplitude": 0.006,
            "wavelength": 0.08,
            "phase_jitter": 1.0,
            "segments": 12,
            "seed": 3,
        },
        "hair": {"albedo": 0.5},
        "render": {"interpenetration": "exit"},
    }
    with pytest.warns(InterpenetrationWarning, match=r"pairs of strands interpenetrate.*interpenetration = \"exit\""):
        scene = scene_from_dict(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_interpenetration(scene.fibers)  # the same assembly: not again
        data["fibers"] = {"generator": "swatch", "count": 12, "layers": 2, "length": 0.2}
        scene_from_dict(data)  # strands that do not touch: no warning
    data["render"]["interpenetration"] = "through"
    with pytest.raises(ValueError, match=r"interpenetration must be one of \['enter', 'exit'\], got 'through'"):
        scene_from_dict(data)


# --- the two rules, on two tubes that cross ---------------------------------------------------------------------
# Strand 0 runs along x, strand 1 along y; both have radius R and their axes cross at the origin. The point
# (0, 0.6R, 0.8R) lies on strand 0's surface and inside strand 1's tube (0.8R from its axis).


@pytest.fixture(scope="module")
def crossing():
    return FiberBVH(two_strands([[-1, 0, 0], [0, 0, 0], [1, 0, 0]], [[0, -1, 0], [0, 0, 0], [0, 1, 0]]))


ON_0_INSIDE_1 = np.array([0.0, 0.6 * R, 0.8 * R])


def test_from_inside_the_other_tube_enter_sees_nothing_exit_sees_where_it_leaves(crossing):
    # A ray leaving strand 0 upward, tilted in x: it leaves strand 1's cylinder x² + z² = R² at the t solving
    # (t dx)² + (0.8R + t dz)² = R².
    d = np.array([0.3, 0.0, 1.0]) / np.hypot(0.3, 1.0)
    t_exit = (-0.8 * R * d[2] + np.sqrt((0.8 * R * d[2]) ** 2 + 0.36 * R * R)) / (d[0] ** 2 + d[2] ** 2)
    enter = intersect(crossing, ON_0_INSIDE_1, d)
    assert enter["segment"][0] == -1 and not occluded(crossing, ON_0_INSIDE_1, d)[0]
    hit = intersect(crossing, ON_0_INSIDE_1, d, rule="exit", skip_strand=0)
    assert hit["strand"][0] == 1 and hit["exit"][0]
    assert hit["t"][0] == pytest.approx(t_exit, rel=1e-5)
    position = ON_0_INSIDE_1 + t_exit * d
    assert np.allclose(hit["position"][0], position, atol=1e-6 * R)
    # Shaded as Cycles shades a back-facing curve hit: the normal turned to face the ray, the tangent reversed;
    # h is then the ray's offset from the axis, as at an entering hit (here x·d over R, in the plane ⊥ y).
    outward = np.array([position[0], 0.0, position[2]]) / R
    assert np.allclose(hit["normal"][0], -outward, atol=1e-5)
    assert np.allclose(hit["tangent"][0], [0, -1, 0], atol=1e-6)
    assert np.dot(hit["normal"][0], d) < 0
    b = np.cross([0, 1, 0], d)
    offset = np.dot(ON_0_INSIDE_1, b) / np.linalg.norm(b) / R
    assert abs(hit["h"][0]) == pytest.approx(abs(offset), abs=1e-5)
    assert occluded(crossing, ON_0_INSIDE_1, d, rule="exit", skip_strand=0)[0]
    # Skipping strand 1 instead: the ray leaves strand 0's surface at t = 0, which t_min excludes.
    assert intersect(crossing, ON_0_INSIDE_1, d, rule="exit", skip_strand=1)["segment"][0] == -1


def test_points_inside_another_strand():
    strands = two_strands([[-1, 0, 0], [0, 0, 0], [1, 0, 0]], [[0, -1, 0], [0, 0, 0], [0, 1, 0]])
    points = [ON_0_INSIDE_1, ON_0_INSIDE_1, [0.5, 0.0, R], [0.0, 0.5, 0.5 * R], [0.0, 0.0, 1.01 * R]]
    inside = points_inside_other_strands(strands, points, [0, 1, 0, 0, -1])
    assert inside.tolist() == [True, False, False, True, False]


def test_both_rules_agree_on_rays_from_outside(crossing):
    # From above, straight down: both rules enter the top of the union, the higher of strand 1 (x² + z² = R²) and
    # strand 0 (y² + z² = R²).
    origin = np.array([[0.5 * R, 0.3, 1.0], [0.4 * R, 0.0, 1.0], [0.0, -0.3, 1.0]])
    d = np.array([0.0, 0.0, -1.0])
    enter = intersect(crossing, origin, np.broadcast_to(d, origin.shape))
    exit_ = intersect(crossing, origin, np.broadcast_to(d, origin.shape), rule="exit")
    for key in ("t", "segment", "strand", "position", "normal", "tangent", "h"):
        assert np.array_equal(enter[key], exit_[key]), key
    assert not exit_["exit"].any()
    top = np.sqrt(np.clip(R * R - np.minimum(origin[:, 0] ** 2, origin[:, 1] ** 2), 0, None))
    expected_t = 1.0 - top
    assert np.allclose(enter["t"], expected_t, rtol=1e-6)


def test_exit_skips_the_whole_strand_the_ray_leaves():
    # One strand bent into a U: two legs along x, 0.1 apart in y. A ray leaving the first leg's top toward the
    # second enters it under the enter rule (another tube of the same strand), not under exit, which skips the
    # whole strand the ray leaves, as Cycles does.
    u = FiberBVH(FiberAssembly.from_strands([(np.array([[-1, 0, 0], [1, 0, 0], [1, 0.1, 0], [-1, 0.1, 0]]), R)]))
    origin = np.array([0.0, R, 0.0])
    d = np.array([0.0, 1.0, 0.0])
    enter = intersect(u, origin, d)
    assert enter["segment"][0] == 2 and enter["t"][0] == pytest.approx(0.1 - 2 * R, rel=1e-5)
    assert intersect(u, origin, d, rule="exit", skip_strand=0)["segment"][0] == -1
    assert not occluded(u, origin, d, rule="exit", skip_strand=0)[0] and occluded(u, origin, d)[0]
    # A camera ray (no strand to skip) from between the legs leaves nothing: it enters the second leg.
    hit = intersect(u, [0.0, 0.05, 0.0], d, rule="exit")
    assert hit["segment"][0] == 2 and not hit["exit"][0]


def test_bad_rule():
    with pytest.raises(ValueError, match="rule must be 'enter' or 'exit'"):
        intersect(
            FiberBVH(two_strands([[0, 0, 0], [1, 0, 0]], [[0, 1, 0], [1, 1, 0]])), [0, 0, 1], [0, 0, -1], rule="cycles"
        )


# --- the rule in the renderer -----------------------------------------------------------------------------------


def small_scene(fibers, rule, light):
    scene = scene_from_dict(
        {
            "camera": {
                "type": "orthographic",
                "origin": [0, 0, 3],
                "target": [0, 0, -0.05],
                "up": [0, 1, 0],
                "width": 0.1,
                "resolution": [12, 12],
            },
            "lights": [{"type": "directional", "direction": light, "irradiance": [3, 3, 3]}],
            "fibers": {"generator": "swatch", "count": 1, "layers": 1},
            "hair": {"albedo": [0.5, 0.35, 0.25], "beta_m": 0.3, "beta_n": 0.4, "alpha": 0.0},
            "render": {"spp": 4, "max_depth": 16, "interpenetration": rule},
        }
    )
    scene.fibers = fibers
    return scene


def test_the_rules_render_alike_where_strands_do_not_overlap_and_apart_where_they_do():
    from warp_hair.geometry.generators import swatch
    from warp_hair.renderer.render import render

    apart = swatch(count=16, layers=2, length=0.12, segments=6, seed=1)
    assert interpenetration(apart).pairs == 0
    tangled = wavy(
        count=16,
        layers=2,
        length=0.12,
        width=0.05,
        amplitude=0.006,
        wavelength=0.06,
        phase_jitter=1.0,
        segments=12,
        seed=1,
    )
    assert interpenetration(tangled).pairs > 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InterpenetrationWarning)
        for light in ([0.2, -0.3, -1.0], [0.0, -0.15, 1.0]):
            same = [render(small_scene(apart, rule, light)) for rule in ("enter", "exit")]
            assert np.array_equal(same[0], same[1])
            differ = [render(small_scene(tangled, rule, light)) for rule in ("enter", "exit")]
            assert not np.array_equal(differ[0], differ[1]) and np.all(np.isfinite(differ[1]))


def test_a_fit_notes_interpenetrating_strands_only_when_another_renderer_made_the_target(tmp_path):
    import shutil

    import targets
    from optimize import load_target
    from optimize.target import interpenetration_note

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InterpenetrationWarning)
        assert interpenetration_note(load_target(targets.path("black_straight"))) is None  # warp-hair's own
        assert interpenetration_note(load_target(targets.path("cycles_brown_straight"))) is None  # apart
        copy = tmp_path / "black_straight"
        shutil.copytree(targets.path("black_straight"), copy)
        spec = copy / "target.toml"
        spec.write_text('renderer = "cycles"\n' + spec.read_text())
        target = load_target(copy)
        note = interpenetration_note(target)
        counted = interpenetration_note(target, 0.01)
    assert note.startswith(
        "the target's strands interpenetrate (237 pairs of 240 strands) and its images were rendered by cycles"
    )
    assert 'interpenetration = "enter"' in note
    # With the model error the fit counts, the note says σ need not cover the renderers' disagreement there.
    assert counted.startswith(note) and "Its σ counts a 1% model error" in counted and "need not cover" in counted


def test_the_gradient_pass_traces_the_exit_rule_paths():
    """The gradient tracer follows the "exit" rule as the forward one does: on one layer of wavy strands that cross
    their neighbours, render_grad's own image is render's, bit for bit (test_render_grad checks the derivative
    along those paths; central differences are swamped here by the discrete choices crossing strands multiply).
    """
    from helpers.scenes import SPARSE_HAIR, sparse_scene_dict

    from warp_hair.renderer.gradients import render_grad
    from warp_hair.renderer.render import render

    data = sparse_scene_dict(SPARSE_HAIR)
    data["fibers"] = {
        "generator": "wavy",
        "count": 24,
        "layers": 1,
        "length": 0.6,
        "radius": 0.004,
        "width": 0.2,
        "amplitude": 0.01,
        "wavelength": 0.15,
        "phase_jitter": 1.0,
        "seed": 3,
    }
    images = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InterpenetrationWarning)
        for rule in ("enter", "exit"):
            data["render"]["interpenetration"] = rule
            scene = scene_from_dict(data)
            images[rule] = render(scene, spp=16, seed=5)
            g, traced = render_grad(scene, np.ones_like(images[rule]), spp=16, seed=5, return_image=True)
            np.testing.assert_array_equal(traced, images[rule])
            assert all(np.all(np.isfinite(v)) for v in g.values())
    assert interpenetration(scene.fibers).pairs >= 5 and not np.array_equal(images["enter"], images["exit"])


def test_the_cycles_swatches_and_their_realisations_have_strands_apart():
    """Issue 23's acceptance compares warp-hair with Cycles on swatches whose strands do not touch (where the
    renderers agree) and fits them with five other realisations of their recipes (benchmarks/
    realisation_acceptance.py): none of those may interpenetrate either."""
    import targets
    from optimize.target import read_target_spec
    from warp_hair.realisation import can_realise, realisation
    from warp_hair.scene import load_scene

    scenes = {}
    for name in targets.names():
        if name.startswith("cycles_"):
            directory = targets.path(name)
            scenes[name] = load_scene(directory / read_target_spec(directory)[0]["scene"])
    recipes = {name: scene for name, scene in scenes.items() if can_realise(scene)}
    assert len(recipes) == 9
    for name, scene in recipes.items():
        for index in range(6):
            report = interpenetration(realisation(scene, index).fibers)
            assert report.pairs == 0, f"{name} realisation {index}: {report.pairs} pairs"
    # Issue 44's swatches of varied strands: a file each (both renderers number the strands alike), drawn as the
    # Catmull-Rom curve through its vertices, as Cycles draws it; those curves must not touch either.
    files = {name: scene for name, scene in scenes.items() if name not in recipes}
    assert sorted(files) == [f"cycles_varied_{look}" for look in ("dark", "light", "medium")]
    for name, scene in files.items():
        assert scene.source["fibers"]["curve"] == "catmull-rom"
        assert interpenetration(scene.fibers).pairs == 0, name
