"""Cubic curves as polylines within a stated distance: the bound holds against curves evaluated densely in
their own textbook forms, Catmull-Rom strands pass through their vertices root first, and scenes and USD
stages take the tolerance."""

import numpy as np
import pytest
from helpers.curves import FORMS, dense_curve, distance_to_polyline
from helpers.scenes import sparse_scene_dict

from warp_hair.geometry import FiberAssembly, catmull_rom, swatch
from warp_hair.geometry.curves import DEFAULT_TOLERANCE, span_count, tessellate
from warp_hair.scene import scene_from_dict

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("basis", list(FORMS))
@pytest.mark.parametrize("max_deviation", [0.05, 0.002])
def test_polyline_stays_within_the_stated_distance(basis, max_deviation):
    cv = np.cumsum(RNG.normal(size=(10 if basis == "bezier" else 8, 3)), axis=0)
    polyline, params, _ = tessellate(cv, basis, "nonperiodic", max_deviation=max_deviation)
    curve = dense_curve(cv, basis)
    worst = distance_to_polyline(curve, polyline).max()
    assert worst <= max_deviation
    # The vertices lie on the curve, at the parameters reported.
    form, step = FORMS[basis]
    spans = span_count(basis, "nonperiodic", len(cv))
    span = np.minimum(params.astype(int), spans - 1)
    on_curve = np.array([form(cv[s * step : s * step + 4], p - s) for s, p in zip(span, params)])
    np.testing.assert_allclose(polyline, on_curve, atol=1e-9)
    # ...and the bound is not met by cutting every span absurdly fine: the tighter bound needs more vertices.
    coarse = tessellate(cv, basis, "nonperiodic", max_deviation=25 * max_deviation)[0]
    assert len(coarse) < len(polyline)


def test_catmull_rom_strands_pass_through_their_vertices_root_first():
    fibers = swatch(count=6, layers=1, length=0.5, radius=0.004, segments=6, drape=0.25, seed=3)
    smooth = catmull_rom(fibers)
    for k in range(fibers.num_strands):
        vertices, _ = fibers.strand(k)
        points, radii = smooth.strand(k)
        np.testing.assert_allclose(points[0], vertices[0], atol=1e-7)
        np.testing.assert_allclose(points[-1], vertices[-1], atol=1e-7)
        # every vertex is a point of the curve, in order
        index = [int(np.argmin(np.linalg.norm(points - v, axis=1))) for v in vertices]
        assert index == sorted(index)
        np.testing.assert_allclose(points[index], vertices, atol=1e-6)
        np.testing.assert_allclose(radii, 0.004, rtol=1e-6)
        # within the tolerance of the Catmull-Rom curve (end vertices repeated)
        cv = np.concatenate([vertices[:1], vertices, vertices[-1:]]).astype(np.float64)
        assert (
            distance_to_polyline(dense_curve(cv, "catmullRom"), points.astype(np.float64)).max()
            <= DEFAULT_TOLERANCE * 0.004 * 1.01
        )  # float32 storage of the vertices


def test_a_straight_strand_stays_straight():
    line = np.linspace([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 5)
    fibers = catmull_rom(FiberAssembly.from_strands([(line, np.full(5, 0.01))]))
    points, _ = fibers.strand(0)
    np.testing.assert_allclose(points[:, [0, 2]], 0.0, atol=1e-7)
    assert np.all(np.diff(points[:, 1]) > 0)


def fibers_table(**options):
    return {"generator": "swatch", "count": 4, "layers": 1, "length": 0.5, "segments": 6, "drape": 0.25, **options}


def test_scene_draws_strands_as_catmull_rom_curves():
    polyline = scene_from_dict({**sparse_scene_dict({"albedo": 0.5}), "fibers": fibers_table()})
    curve = scene_from_dict({**sparse_scene_dict({"albedo": 0.5}), "fibers": fibers_table(curve="catmull-rom")})
    finer = scene_from_dict(
        {**sparse_scene_dict({"albedo": 0.5}), "fibers": fibers_table(curve="catmull-rom", tolerance=0.001)}
    )
    assert polyline.fibers.num_segments < curve.fibers.num_segments < finer.fibers.num_segments


@pytest.mark.parametrize(
    "options,message",
    [
        ({"curve": "bezier"}, r"\[fibers\] curve must be one of \['polyline', 'catmull-rom'\], got 'bezier'"),
        ({"tolerance": 0.01}, r"\[fibers\] tolerance applies to curve = \"catmull-rom\""),
        ({"curve": "catmull-rom", "tolerance": 0.0}, r"\[fibers\] tolerance must be a positive number"),
        ({"curve": "catmull-rom", "tolerance": "1%"}, r"\[fibers\] tolerance must be a number, got '1%'"),
        ({"curve": "catmull-rom", "tolerance": 1e-12}, r"would need \d+ straight pieces .* raise the tolerance"),
    ],
)
def test_bad_curve_options_are_named(options, message):
    with pytest.raises(ValueError, match=message):
        scene_from_dict({**sparse_scene_dict({"albedo": 0.5}), "fibers": fibers_table(**options)})
