"""Tests of warp_hair.geometry: the fiber container, its two file formats and the procedural generators."""

import hashlib
import itertools
import struct
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from helpers.scenes import front_camera

from warp_hair.geometry.assembly import FiberAssembly, FiberDataError
from warp_hair.geometry.formats import load_fibers, save_fibers
from warp_hair.geometry.generators import curly, fur, swatch, wavy
from warp_hair.realisation import realisation_draw
from warp_hair.scene import GENERATORS as SCENE_GENERATORS
from warp_hair.scene import scene_from_dict

BENCH_FIBERS = Path(__file__).parents[1] / "benchmarks" / "standard_swatch_fibers.txt"
GENERATORS = [swatch, wavy, curly, fur]


def mixed_assembly():
    """Three strands of 2, 3 and 5 vertices with distinct radii."""
    rng = np.random.default_rng(7)
    strands = [(rng.normal(size=(n, 3)), rng.uniform(0.001, 0.01, n)) for n in (2, 3, 5)]
    return FiberAssembly.from_strands(strands)


# --- FiberAssembly ---------------------------------------------------------------------------------------------


def test_accessors():
    fibers = mixed_assembly()
    assert (fibers.num_strands, fibers.num_vertices, fibers.num_segments) == (3, 10, 7)
    assert fibers.points.dtype == np.float32 and fibers.radii.dtype == np.float32
    assert fibers.strand_offsets.tolist() == [0, 2, 5, 10]
    assert fibers.vertex_counts.tolist() == [2, 3, 5]
    points, radii = fibers.strand(1)
    np.testing.assert_array_equal(points, fibers.points[2:5])
    np.testing.assert_array_equal(radii, fibers.radii[2:5])
    np.testing.assert_array_equal(fibers.strand(-1)[0], fibers.points[5:])
    with pytest.raises(IndexError):
        fibers.strand(3)


def test_segments_shapes_and_strand_ids():
    fibers = mixed_assembly()
    p0, p1, r0, r1, strand_id, index = fibers.segments()
    assert p0.shape == p1.shape == (7, 3)
    assert r0.shape == r1.shape == (7,)
    assert strand_id.dtype == index.dtype == np.int32
    assert strand_id.tolist() == [0, 1, 1, 2, 2, 2, 2]
    assert index.tolist() == [0, 0, 1, 0, 1, 2, 3]
    for k, i, a, b, ra, rb in zip(strand_id, index, p0, p1, r0, r1):
        points, radii = fibers.strand(k)
        np.testing.assert_array_equal([a, b], points[i : i + 2])
        np.testing.assert_array_equal([ra, rb], radii[i : i + 2])


def test_bounds_include_radii():
    fibers = FiberAssembly([[0, 0, 0], [1, 2, 3]], [0.5, 0.25], [0, 2])
    lo, hi = fibers.bounds()
    np.testing.assert_allclose(lo, [-0.5, -0.5, -0.5])
    np.testing.assert_allclose(hi, [1.25, 2.25, 3.25])


def test_concatenate_keeps_strands_in_order():
    a, b = mixed_assembly(), swatch(count=8, layers=2, seed=3)
    both = FiberAssembly.concatenate([a, b])
    assert both.num_strands == a.num_strands + b.num_strands
    np.testing.assert_array_equal(both.strand(3)[0], b.strand(0)[0])
    np.testing.assert_array_equal(both.strand(2)[1], a.strand(2)[1])
    assert FiberAssembly.concatenate([]).num_strands == 0


def test_arrays_are_private_and_read_only():
    points = np.zeros((2, 3))
    fibers = FiberAssembly(points, [1, 1], [0, 2])
    points[0, 0] = np.nan
    assert np.isfinite(fibers.points).all()
    with pytest.raises(ValueError):
        fibers.points[0, 0] = 1.0


@pytest.mark.parametrize(
    "points, radii, offsets, expected",
    [
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [1, 1, 1], [0, 2, 3], "strand 1: has 1 vertex"),
        ([[0, 0, 0], [1, 0, 0], [2, np.nan, 0], [3, 0, 0]], [1] * 4, [0, 2, 4], "strand 1, vertex 0"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [1, 1, 1, np.inf], [0, 2, 4], "strand 1, vertex 1"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [1, 0, 1, 1], [0, 2, 4], "strand 0, vertex 1"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], [1, 1, -1, 1], [0, 2, 4], "strand 1, vertex 0"),
    ],
)
def test_construction_names_the_bad_strand(points, radii, offsets, expected):
    with pytest.raises(FiberDataError, match=expected):
        FiberAssembly(points, radii, offsets, source="hair.txt")


# --- Files -----------------------------------------------------------------------------------------------------


def assert_same_fibers(a, b, atol=0.0):
    np.testing.assert_array_equal(a.strand_offsets, b.strand_offsets)
    np.testing.assert_allclose(a.points, b.points, rtol=0, atol=atol)
    np.testing.assert_allclose(a.radii, b.radii, rtol=0, atol=atol)


@pytest.mark.parametrize("fibers", [mixed_assembly(), curly(count=12, layers=2, seed=4)], ids=["mixed", "curly"])
def test_hair_round_trip_is_exact(tmp_path, fibers):
    save_fibers(fibers, tmp_path / "fibers.hair")
    assert_same_fibers(load_fibers(tmp_path / "fibers.hair"), fibers)


@pytest.mark.parametrize("fibers", [mixed_assembly(), curly(count=12, layers=2, seed=4)], ids=["mixed", "curly"])
def test_text_round_trip(tmp_path, fibers):
    save_fibers(fibers, tmp_path / "fibers.txt")
    assert_same_fibers(load_fibers(tmp_path / "fibers.txt"), fibers, atol=1e-6)


def test_hair_writer_follows_the_format(tmp_path):
    fibers = mixed_assembly()
    save_fibers(fibers, tmp_path / "f.hair")
    data = (tmp_path / "f.hair").read_bytes()
    signature, strands, points, flags = struct.unpack_from("<4s3I", data)
    assert (signature, strands, points, flags) == (b"HAIR", 3, 10, 0b111)
    segments = np.frombuffer(data, "<u2", 3, 128)
    assert segments.tolist() == [1, 2, 4]
    xyz = np.frombuffer(data, "<f4", 30, 134).reshape(-1, 3)
    thickness = np.frombuffer(data, "<f4", 10, 134 + 120)
    np.testing.assert_array_equal(xyz, fibers.points)
    np.testing.assert_array_equal(thickness, 2 * fibers.radii)  # thickness is the diameter
    assert len(data) == 134 + 120 + 40


def hair_bytes(
    segments=None,
    points=None,
    thickness=None,
    transparency=None,
    colour=None,
    *,
    strands,
    total,
    default_segments=0,
    default_thickness=1.0,
    signature=b"HAIR",
):
    """A .hair file built straight from the format description, independently of the writer."""
    arrays = [(segments, "<u2"), (points, "<f4"), (thickness, "<f4"), (transparency, "<f4"), (colour, "<f4")]
    flags = sum(1 << bit for bit, (array, _) in enumerate(arrays) if array is not None)
    header = struct.pack(
        "<4s4I5f88s", signature, strands, total, flags, default_segments, default_thickness, 0, 1, 1, 1, b"test"
    )
    return header + b"".join(np.asarray(a, dtype).tobytes() for a, dtype in arrays if a is not None)


def test_hair_reader_uses_defaults_for_absent_arrays(tmp_path):
    points = np.arange(18, dtype=np.float32).reshape(6, 3)
    data = hair_bytes(
        points=points,
        transparency=np.zeros(6),
        colour=np.ones((6, 3)),
        strands=2,
        total=6,
        default_segments=2,
        default_thickness=0.01,
    )
    (tmp_path / "defaults.hair").write_bytes(data)
    fibers = load_fibers(tmp_path / "defaults.hair")
    assert fibers.vertex_counts.tolist() == [3, 3]
    np.testing.assert_array_equal(fibers.points, points)
    np.testing.assert_array_equal(fibers.radii, np.float32(0.005))


def test_hair_writer_rejects_strands_longer_than_uint16(tmp_path):
    long_strand = FiberAssembly(np.zeros((65537, 3)), np.ones(65537), [0, 65537])
    with pytest.raises(ValueError, match="strand 3: has 65536 segments"):
        save_fibers(FiberAssembly.concatenate([mixed_assembly(), long_strand]), tmp_path / "long.hair")


GOOD_POINTS = np.arange(27, dtype=np.float32).reshape(9, 3)
GOOD_HAIR = {"segments": [2, 3, 1], "points": GOOD_POINTS, "thickness": np.full(9, 0.02), "strands": 3, "total": 9}


def with_nan_at(index):
    points = GOOD_POINTS.copy()
    points[index, 1] = np.nan
    return points


def with_thickness(index, value):
    thickness = np.full(9, 0.02)
    thickness[index] = value
    return thickness


# (file bytes, what the message must also say). Strands of 3, 4 and 2 vertices: 0-2, 3-6, 7-8.
MALFORMED_HAIR = {
    "header truncated": (hair_bytes(**GOOD_HAIR)[:100], "header"),
    "bad signature": (hair_bytes(**GOOD_HAIR, signature=b"HAIX"), "signature"),
    "segments truncated": (hair_bytes(**GOOD_HAIR)[: 128 + 3], "strand 1"),
    "points truncated": (hair_bytes(**GOOD_HAIR)[: 134 + 12 * 5 + 4], "strand 1"),
    "thickness truncated": (hair_bytes(**GOOD_HAIR)[: 134 + 108 + 4 * 8], "strand 2"),
    "default layout truncated": (
        hair_bytes(points=GOOD_POINTS, strands=3, total=9, default_segments=2)[: 128 + 12 * 7],
        "strand 2",
    ),
    "NaN point": (hair_bytes(**{**GOOD_HAIR, "points": with_nan_at(4)}), "strand 1, vertex 1"),
    "infinite thickness": (hair_bytes(**{**GOOD_HAIR, "thickness": with_thickness(8, np.inf)}), "strand 2"),
    "zero thickness": (hair_bytes(**{**GOOD_HAIR, "thickness": with_thickness(3, 0.0)}), "strand 1, vertex 0"),
    "one-vertex strand": (hair_bytes(**{**GOOD_HAIR, "segments": [2, 0, 4]}), "strand 1: has 1 vertex"),
    "too many points in strands": (hair_bytes(**{**GOOD_HAIR, "segments": [2, 6, 1]}), "strand 1"),
    "too few points in strands": (hair_bytes(**{**GOOD_HAIR, "segments": [2, 2, 1]}), "strand 2"),
    "no points array": (hair_bytes(segments=[1], strands=1, total=2), "no points"),
}


@pytest.mark.parametrize("case", MALFORMED_HAIR)
def test_malformed_hair_names_file_and_strand(tmp_path, case):
    data, expected = MALFORMED_HAIR[case]
    path = tmp_path / "bad_model.hair"
    path.write_bytes(data)
    with pytest.raises(ValueError, match=r"bad_model.hair") as raised:
        load_fibers(path)
    assert expected in str(raised.value)


def test_good_hair_bytes_load(tmp_path):
    (tmp_path / "good.hair").write_bytes(hair_bytes(**GOOD_HAIR))
    fibers = load_fibers(tmp_path / "good.hair")
    assert fibers.vertex_counts.tolist() == [3, 4, 2]
    np.testing.assert_array_equal(fibers.radii, np.float32(0.01))


GOOD_TEXT = """# three strands
0 0 0 0.1
0 1 0 0.1

1 0 0 0.1
1 1 0 0.1
1 2 0 0.1

2 0 0 0.1
2 1 0 0.1
"""


def test_text_reader_handles_comments_blank_runs_and_whitespace(tmp_path):
    text = "\n\n" + GOOD_TEXT.replace("1 1 0 0.1", "# inside a strand\n\t1  1 0 0.1  ").replace("\n\n", "\n \n\n")
    (tmp_path / "messy.txt").write_text(text)
    fibers = load_fibers(tmp_path / "messy.txt")
    assert fibers.vertex_counts.tolist() == [2, 3, 2]
    np.testing.assert_array_equal(fibers.strand(1)[0][1], [1, 1, 0])


def test_text_writer_format(tmp_path):
    save_fibers(mixed_assembly(), tmp_path / "f.txt")
    lines = (tmp_path / "f.txt").read_text().splitlines()
    # Numbers only (Mitsuba's curve loaders take no comment lines): 4 a vertex, a blank line between strands.
    assert sum(not line for line in lines) == 2
    assert all(len(line.split()) == 4 and all(float(v) == float(v) for v in line.split()) for line in lines if line)
    assert sum(1 for line in lines if line) == mixed_assembly().num_vertices


@pytest.mark.parametrize(
    "replacement",
    ["1 1 0", "1 1 0 0.1 5", "1 x 0 0.1", "1 nan 0 0.1", "1 1 inf 0.1", "1 1 0 0", "1 1 0 -0.1", "1 1 0 1e40"],
)
def test_malformed_text_names_file_line_and_strand(tmp_path, replacement):
    path = tmp_path / "bad_curves.txt"
    path.write_text(GOOD_TEXT.replace("1 1 0 0.1", replacement))
    with pytest.raises(ValueError, match=r"bad_curves.txt: line 6: strand 1"):
        load_fibers(path)


def test_text_strand_of_one_vertex(tmp_path):
    path = tmp_path / "short.txt"
    path.write_text(GOOD_TEXT.replace("2 1 0 0.1\n", ""))
    with pytest.raises(ValueError, match=r"short.txt: line 9: strand 2: has 1 vertex"):
        load_fibers(path)


def test_binary_file_with_text_extension(tmp_path):
    path = tmp_path / "binary.txt"
    path.write_bytes(b"\xff\xfe\x00HAIR")
    with pytest.raises(ValueError, match=r"binary.txt"):
        load_fibers(path)


def test_unknown_extension(tmp_path):
    with pytest.raises(ValueError, match=r"unknown fiber file extension '.obj'"):
        load_fibers(tmp_path / "model.obj")
    with pytest.raises(ValueError, match=r"model.ply"):
        save_fibers(mixed_assembly(), tmp_path / "model.ply")


def test_bench_swatch_loads():
    fibers = load_fibers(BENCH_FIBERS)
    assert fibers.num_strands == 640
    assert (fibers.vertex_counts == 9).all()
    np.testing.assert_array_equal(fibers.radii, np.float32(0.004))


# --- Generators ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("generator", GENERATORS)
def test_generators_are_deterministic_per_seed(generator):
    a, b, c = generator(seed=1), generator(seed=1), generator(seed=2)
    assert_same_fibers(a, b)
    assert a.strand_offsets.tolist() == c.strand_offsets.tolist()
    assert not np.array_equal(a.points, c.points)


def layer_slices(fibers, layers):
    per_layer = fibers.num_strands // layers
    points = fibers.points.reshape(fibers.num_strands, -1, 3)
    return [points[k * per_layer : (k + 1) * per_layer] for k in range(layers)]


def test_swatch_defaults():
    fibers = swatch()
    assert fibers.num_strands == 640
    assert (fibers.vertex_counts == 9).all()
    np.testing.assert_array_equal(fibers.radii, np.float32(0.004))
    y = fibers.points[:, 1]
    assert y.min() == pytest.approx(-0.7) and y.max() == pytest.approx(0.7)
    # The documented default width: spacing 2.1 r / (1 - 1.25 jitter) times 160 fibers per layer.
    width = 160 * 2.1 * 0.004 / (1 - 1.25 * 0.25)
    x = fibers.points[:, 0]
    assert np.abs(x).max() <= width / 2
    assert x.max() - x.min() > 0.97 * width


def test_swatch_layers_at_distinct_depths():
    layers = layer_slices(swatch(), 4)
    z_ranges = [(layer[..., 2].min(), layer[..., 2].max()) for layer in layers]
    assert z_ranges[0][1] <= 0.004  # the front layer lies at z = 0
    for (front_lo, _), (_, back_hi) in itertools.pairwise(z_ranges):
        assert back_hi < front_lo


@pytest.mark.parametrize("kwargs", [{}, {"jitter": 0.4, "seed": 5}, {"count": 90, "layers": 3, "radius": 0.01}])
def test_swatch_fibers_never_intersect(kwargs):
    fibers = swatch(**kwargs)
    points = fibers.points.reshape(fibers.num_strands, -1, 3)
    radius = fibers.radii[0]
    for row in range(points.shape[1]):
        xz = points[:, row, [0, 2]].astype(np.float64)
        distance = np.linalg.norm(xz[:, None] - xz[None], axis=-1)
        np.fill_diagonal(distance, np.inf)
        assert distance.min() >= 2 * radius


def test_swatch_half_spacing_stagger_closes_gaps():
    fibers = swatch(jitter=0.0)
    front, second = (np.sort(layer[:, 0, 0]) for layer in layer_slices(fibers, 4)[:2])
    spacing = np.diff(front).mean()
    np.testing.assert_allclose(second - front, spacing / 2, atol=1e-6)
    # Seen from +z, neighbouring silhouettes of the two front layers overlap: nothing shows through.
    edges = np.sort(np.concatenate([front, second]))
    assert np.diff(edges).max() < 2 * 0.004


def test_swatch_width_and_spacing():
    narrow = swatch(width=1.2)
    assert np.abs(narrow.points[:, 0]).max() <= 0.6
    assert np.ptp(narrow.points[:, 0]) > 1.15
    spaced = swatch(count=40, layers=2, spacing=0.02, jitter=0.0)
    assert np.ptp(spaced.points[:, 0]) == pytest.approx(20 * 0.02 - 0.02 / 2)
    uneven = swatch(count=10, layers=3)
    assert uneven.num_strands == 10
    with pytest.raises(ValueError, match="not both"):
        swatch(width=1.0, spacing=0.01)
    with pytest.raises(ValueError, match="jitter"):
        swatch(jitter=0.5)
    with pytest.raises(ValueError, match="layers"):
        swatch(count=3, layers=4)


def test_wavy_waves_are_resolved_and_have_the_amplitude():
    fibers = wavy(count=8, layers=1, amplitude=0.05, wavelength=0.2, jitter=0.0)
    points = fibers.points.reshape(8, -1, 3)
    assert points.shape[1] >= 12 * 1.4 / 0.2
    swing = points[..., 0] - points[..., 0].mean(axis=1, keepdims=True)
    assert np.abs(swing).max() == pytest.approx(0.05, rel=0.02)
    assert np.all(points[..., 2] == points[:, :1, 2])  # waves stay in the swatch plane


def test_curly_helices_have_the_curl_radius():
    fibers = curly(count=6, layers=1, length=1.0, curl_radius=0.03, pitch=0.1, jitter=0.0)
    points = fibers.points.reshape(6, -1, 3).astype(np.float64)[:, :-1]  # whole turns only
    axis = points.mean(axis=1, keepdims=True)
    distance = np.hypot(points[..., 0] - axis[..., 0], points[..., 2] - axis[..., 2])
    np.testing.assert_allclose(distance, 0.03, rtol=1e-4)
    assert fibers.vertex_counts[0] == 16 * 10 + 1


def test_fur_rises_from_the_patch():
    fibers = fur(count=500, patch=(0.4, 0.2), length=0.1, root_radius=0.002, tip_radius=0.0005, seed=3)
    points = fibers.points.reshape(500, -1, 3)
    roots, tips = points[:, 0], points[:, -1]
    assert np.all(np.abs(roots[:, 0]) <= 0.2) and np.all(np.abs(roots[:, 1]) <= 0.1)
    np.testing.assert_array_equal(roots[:, 2], 0)
    assert np.all(np.diff(points[..., 2], axis=1) > 0)  # every fiber keeps rising: tips above roots
    assert np.all(tips[:, 2] > roots[:, 2])
    lengths = np.linalg.norm(np.diff(points, axis=1), axis=-1).sum(axis=1)
    assert np.all((lengths >= 0.08 - 1e-6) & (lengths <= 0.12 + 1e-6))
    radii = fibers.radii.reshape(500, -1)
    np.testing.assert_allclose(radii[:, 0], 0.002)
    np.testing.assert_allclose(radii[:, -1], 0.0005)
    assert np.all(np.diff(radii, axis=1) < 0)


def test_fur_rejects_fibers_that_would_not_rise():
    with pytest.raises(ValueError, match="lean"):
        fur(lean=60, bend=40)


@pytest.mark.parametrize(
    "patch, pattern",
    [
        (0, r"^patch must be a positive finite number, got 0.0$"),
        ((0.5, 0.0), r"^patch\[1\] must be a positive finite number, got 0.0$"),
        ((0.5, 0.5, 0.5), r"^patch must be one number .* or two"),
    ],
)
def test_fur_errors_name_the_patch_as_written(patch, pattern):
    """The error names the key the user wrote (patch, or one of its two entries), not an internal name."""
    with pytest.raises(ValueError, match=pattern):
        fur(count=5, patch=patch)


def test_draped_swatch_lies_on_its_cylinder():
    """drape bends the flat swatch over a cylinder (axis along x at z = −R): each fiber keeps its distance to the
    axis (R + its flat z) and its length along y becomes arc length."""
    from warp_hair.geometry.generators import swatch

    flat = swatch(count=12, layers=2, length=0.5, width=0.2, segments=48, jitter=0.0, seed=2)
    draped = swatch(count=12, layers=2, length=0.5, width=0.2, segments=48, jitter=0.0, seed=2, drape=0.25)
    p, q = flat.points, draped.points
    np.testing.assert_allclose(q[:, 0], p[:, 0])
    np.testing.assert_allclose(np.hypot(q[:, 1], q[:, 2] + 0.25), 0.25 + p[:, 2], rtol=1e-6)  # float32 points
    for k in range(draped.num_strands):
        points = draped.strand(k)[0]
        arc = np.linalg.norm(np.diff(points, axis=0), axis=1).sum()
        z_flat = flat.strand(k)[0][0, 2]
        assert arc == pytest.approx(0.5 * (0.25 + z_flat) / 0.25, rel=1e-3)  # chords of a 48-segment arc
    with pytest.raises(ValueError, match=r"drape = 0.1 is too tight"):
        swatch(count=12, layers=2, length=0.5, width=0.2, drape=0.1)


# Per shipped target whose scenes use a generator (and the example scene): the SHA-256 (first 32 hex digits) of
# its strands' float32 points and radii, and of realisation 1's (`warp_hair.realisation`), recorded with the
# generators as they were before clumps, strays and per-layer phases (commit 702ed71) by hashing
# GENERATORS[name](**[fibers]).
SHIPPED_STRANDS = {
    "auburn_curly": ("1dd03b0a5f2b13960b86ebf3323e50ee", "020207a7f13ddbca6ca085e718b52253"),
    "auburn_light_tips_varied": ("42ec6caa09e305bc8e21c6c70b9b10c9", "45e88d9e39e135ac64fc7349e2cc29d1"),
    "black_straight": ("05b6762fe1cfca874f2392cf12e455f2", "09ee49cdfa1ff6cd7f4b224e8ed85c23"),
    "blonde_straight": ("a62d5470f0d0a01a4eccd80bb0a65035", "db08acd025f30b291a40846f09e5a0c9"),
    "brown_light_tips": ("7779424dcc84675fd94401cc7d38bf09", "51b8cef793cd361512c536d945cb7c77"),
    "brown_wavy": ("fc5b9b69f6c5b0473de3b261394049e7", "e84f295415e6e5d6af213cc864bd078e"),
    "chestnut_straight": ("cd266fa8872fa48be3426f86441ffe80", "4aa5d2d3fedfbd59e76f88d415ec25a2"),
    "cycles_blonde_curly": ("c51d3de50848342aa5cb804237432fe8", "3543fe7763dd6749b4a7f7a31d6661c3"),
    "cycles_blonde_straight": ("a84fb54e11a6212c40ee882ae6fa9cf3", "b2620b78ccf7e25d85b695968184a377"),
    "cycles_blonde_wavy": ("d455d776bb312cb3d7d37f6284f76c4b", "9e819b0c3cebe35ea5465b34783ef449"),
    "cycles_brown_curly": ("fe6c54f4bfe58e1e17394d37e8a11af5", "08adbda25e742cd91bab0eec74244e27"),
    "cycles_brown_straight": ("d8b335d571e2a99fadf92beb758270dd", "f6c02145eae5d7a8a69a666d1d4b8543"),
    "cycles_brown_wavy": ("f19d48459e6fcac7d1c4f20b35c3b80d", "4411e9e0742214d6d8e31817d0f2a81c"),
    "cycles_dark_curly": ("1af48e3df7f604d251073f4f2210c9bd", "3be1ddd067813b4f7e7d33ec0e4efda1"),
    "cycles_dark_straight": ("69ba0c6005bd5f465d6bb14daa315065", "06fd281e39cfc188f51c12b07d21fdc2"),
    "cycles_dark_wavy": ("51df500b8a9da8fba0e99c4be6fcb3d1", "93cda2f0fd90226a0ed6094bf0c7e78b"),
    "fur_patch": ("073b04517d2583f88285d39a0597eb0d", "0a78c236dc5f9ed1c440882357a65627"),
    "mitsuba_blonde_straight": ("a84fb54e11a6212c40ee882ae6fa9cf3", "b2620b78ccf7e25d85b695968184a377"),
    "mitsuba_brown_straight": ("d8b335d571e2a99fadf92beb758270dd", "f6c02145eae5d7a8a69a666d1d4b8543"),
    "mitsuba_dark_wavy": ("51df500b8a9da8fba0e99c4be6fcb3d1", "93cda2f0fd90226a0ed6094bf0c7e78b"),
    "photo_blonde_straight_jpeg": ("a84fb54e11a6212c40ee882ae6fa9cf3", "b2620b78ccf7e25d85b695968184a377"),
    "photo_blonde_straight_png": ("a84fb54e11a6212c40ee882ae6fa9cf3", "b2620b78ccf7e25d85b695968184a377"),
    "photo_brown_straight_jpeg": ("d8b335d571e2a99fadf92beb758270dd", "f6c02145eae5d7a8a69a666d1d4b8543"),
    "photo_brown_straight_png": ("d8b335d571e2a99fadf92beb758270dd", "f6c02145eae5d7a8a69a666d1d4b8543"),
    "photo_dark_wavy_jpeg": ("51df500b8a9da8fba0e99c4be6fcb3d1", "93cda2f0fd90226a0ed6094bf0c7e78b"),
    "photo_dark_wavy_png": ("51df500b8a9da8fba0e99c4be6fcb3d1", "93cda2f0fd90226a0ed6094bf0c7e78b"),
    "examples/swatch.toml": ("dd24eb52c82c4a12db21f79508dacfdb", "6e5eac57201981556d9693cb131264b4"),
    # The recipes of the swatches Blender made (benchmarks/blender_swatch_acceptance.py), recorded when shipped
    # (2026-12-05); a photo target states the same recipe as its EXR one.
    "blender_straight": ("3f36409fa522269fe0574275c2139cea", "166bada77f7667206ae8faf354f9f900"),
    "blender_straight_png": ("3f36409fa522269fe0574275c2139cea", "166bada77f7667206ae8faf354f9f900"),
    "blender_wavy": ("3118c7bcf9f1c043029081c981c0a9bb", "c1ed5aa999be17716d1f9d03b90a1c33"),
    "blender_wavy_jpeg": ("3118c7bcf9f1c043029081c981c0a9bb", "c1ed5aa999be17716d1f9d03b90a1c33"),
    "blender_clumped": ("525bc24d289ffb425ebd96e7e8eb2aaa", "58701895dece5ed5e1e259caddb520ab"),
    "blender_clumped_png": ("525bc24d289ffb425ebd96e7e8eb2aaa", "58701895dece5ed5e1e259caddb520ab"),
    "blender_thick": ("9cfc773eeb196041edd1349d6226003f", "39442312060e29956bb1e6a4104095cd"),
    "blender_thick_jpeg": ("9cfc773eeb196041edd1349d6226003f", "39442312060e29956bb1e6a4104095cd"),
}


def _strands_digest(assembly):
    data = np.ascontiguousarray(assembly.points).tobytes() + np.ascontiguousarray(assembly.radii).tobytes()
    return hashlib.sha256(data).hexdigest()[:32]


def test_every_shipped_scene_generates_the_strands_it_always_did():
    """New generator keys default to the recipes as they were: every shipped target's scene (and the example)
    gives bit for bit the strands, and the realisation, it gave before they were added. (The points are float32
    from float64 sums and sines: a platform's sine differing in its last bit changes a float32 only within a
    float64 ulp of a rounding boundary, about one value in 2^29.)"""
    root = Path(__file__).parents[1]
    generated = [
        path.parent.name
        for path in root.glob("targets/*/scene_front.toml")
        if "generator" in tomllib.loads(path.read_text())["fibers"]
    ]
    assert sorted(SHIPPED_STRANDS) == sorted([*generated, "examples/swatch.toml"])
    for name, (expected, expected_other) in SHIPPED_STRANDS.items():
        path = root / name if "/" in name else root / "targets" / name / "scene_front.toml"
        table = tomllib.loads(path.read_text())["fibers"]
        generator = SCENE_GENERATORS[table["generator"]]
        arguments = {k: v for k, v in table.items() if k not in ("generator", "curve", "tolerance")}
        assert _strands_digest(generator(**arguments)) == expected, path
        draw = realisation_draw(SimpleNamespace(source={"fibers": table}), 1)
        assert _strands_digest(generator(**{**arguments, **draw})) == expected_other, path


def _front_swing(generator, **kwargs):
    """Per fiber, its wave: x minus the straight swatch's axes, which the same seed draws alike."""
    waved = generator(**kwargs).points.reshape(kwargs["count"], -1, 3)
    straight_keys = ("count", "layers", "length", "width", "segments", "seed", "jitter")
    straight = swatch(**{k: kwargs[k] for k in straight_keys}).points.reshape(kwargs["count"], -1, 3)
    return (waved[..., 0] - straight[..., 0]).astype(np.float64)


def test_layer_phase_jitter_gives_each_layer_its_own_wave_and_keeps_the_front_layers():
    recipe = {
        "count": 30,
        "layers": 3,
        "length": 0.5,
        "width": 0.2,
        "segments": 40,
        "seed": 4,
        "jitter": 0.1,
        "phase_jitter": 0.0,
    }
    in_step = _front_swing(wavy, **recipe, wavelength=0.25)
    by_layer = _front_swing(wavy, **recipe, wavelength=0.25, layer_phase_jitter=1.0)
    layers = [slice(10 * k, 10 * (k + 1)) for k in range(3)]
    for part in layers:  # within a layer the fibers wave in step (phase_jitter 0)
        np.testing.assert_allclose(by_layer[part], by_layer[part][:1].repeat(10, 0), atol=1e-6)
    np.testing.assert_allclose(by_layer[layers[0]], in_step[layers[0]], atol=1e-6)  # the front layer at `phase`
    np.testing.assert_allclose(in_step, in_step[:1].repeat(30, 0), atol=1e-6)  # without it, one phase for all
    # The deeper layers' offsets from the front's, over 20 seeds: uniform in [0, 2π · 0.5).
    y = np.linspace(-0.25, 0.25, 41)[:-1]  # two whole waves
    offsets = []
    for seed in range(20):
        swing = _front_swing(wavy, **{**recipe, "seed": seed}, wavelength=0.25, layer_phase_jitter=0.5)[::10, :-1]
        phase = np.angle(swing @ np.exp(-2j * np.pi * y / 0.25)) + np.pi / 2  # sin(φ + ωy): its φ
        offsets += list(np.mod(phase[1:] - phase[0], 2 * np.pi))
    offsets = np.array(offsets)
    assert np.all((offsets < np.pi + 1e-3) | (offsets > 2 * np.pi - 1e-3))
    assert np.std(offsets) == pytest.approx(np.pi / np.sqrt(12), rel=0.35)  # 40 draws: ±11% (1σ)
    curled = curly(count=30, layers=3, length=0.4, segments=40, seed=4, phase_jitter=0.0, layer_phase_jitter=0.5)
    flat = curly(count=30, layers=3, length=0.4, segments=40, seed=4, phase_jitter=0.0)
    np.testing.assert_array_equal(curled.points[: 10 * 41], flat.points[: 10 * 41])
    assert not np.allclose(curled.points[10 * 41 :], flat.points[10 * 41 :])


def test_layer_shift_jitter_moves_each_deeper_layer_across_as_one_and_keeps_the_front_layer():
    """Layer k > 0 moves across by its own offset, uniform in [0, layer_shift_jitter) spacings and affine in it
    (the same draw scaled), wrapping at the edges; the front layer, depths and the other draws stay; 0 is the
    stagger as before, bit for bit."""
    recipe = {"count": 40, "layers": 4, "length": 0.3, "width": 0.2, "segments": 4, "seed": 3, "jitter": 0.1}
    spacing = 0.2 / 10

    def roots(**keys):
        return swatch(**{**recipe, **keys}).points.reshape(40, -1, 3)[:, 0].astype(np.float64)

    plain = roots()
    np.testing.assert_array_equal(roots(layer_shift_jitter=0.0), plain)
    full, half = roots(layer_shift_jitter=1.0), roots(layer_shift_jitter=0.5)
    np.testing.assert_array_equal(full[:10], plain[:10])  # the front layer stays
    np.testing.assert_allclose(full[:, 2], plain[:, 2], atol=1e-7)  # depths are not moved
    assert not np.allclose(full[10:, 0], plain[10:, 0], atol=0.1 * spacing)

    def offsets(moved, base):  # per deeper layer, its shift in spacings: sorted x against sorted x, mod a spacing
        layers = [slice(10 * k, 10 * (k + 1)) for k in range(1, 4)]
        return np.array(
            [np.median(np.mod((np.sort(moved[k, 0]) - np.sort(base[k, 0])) / spacing, 1.0)) for k in layers]
        )

    np.testing.assert_allclose(offsets(half, plain), 0.5 * offsets(full, plain), atol=1e-4)
    # Over 30 seeds, the offsets are uniform in [0, 1) spacings: mean ½, spread 1/√12.
    many = np.concatenate([offsets(roots(seed=seed, layer_shift_jitter=1.0), roots(seed=seed)) for seed in range(30)])
    assert np.mean(many) == pytest.approx(0.5, abs=0.11)  # 90 draws: ±0.03 (1σ)
    assert np.std(many) == pytest.approx(1 / np.sqrt(12), rel=0.15)  # ±5% (1σ)


def test_clumps_pull_each_fiber_toward_the_nearest_guide_toward_the_tips():
    recipe = {"count": 60, "layers": 3, "length": 0.4, "width": 0.3, "segments": 20, "seed": 6}
    plain = swatch(**recipe).points.reshape(60, -1, 3).astype(np.float64)
    tight = swatch(**recipe, clumps=5, clump_strength=1.0).points.reshape(60, -1, 3).astype(np.float64)
    half = swatch(**recipe, clumps=5, clump_strength=0.5).points.reshape(60, -1, 3).astype(np.float64)
    np.testing.assert_allclose(tight[:, 0], plain[:, 0], atol=1e-7)  # roots stay
    guides = np.flatnonzero(np.all(np.abs(tight - plain) < 1e-7, axis=(1, 2)))
    assert len(guides) == 5  # only the guides keep their whole course
    nearest = guides[np.argmin(np.abs(plain[:, None, 0, 0] - plain[guides, 0, 0]), axis=1)]
    np.testing.assert_allclose(tight[:, -1], plain[nearest, -1], atol=1e-6)  # at strength 1 the tips meet the guide
    # Pulled by strength × height: at the tips half way at 0.5, a quarter of the way half way up.
    t = np.linspace(0, 1, 21)[None, :, None]
    np.testing.assert_allclose(half, plain + 0.5 * t * (plain[nearest] - plain), atol=1e-6)
    assert len(np.unique(tight[:, -1].round(6), axis=0)) == 5


def test_strays_leave_the_front_surface_and_the_rest_stay():
    recipe = {"count": 40, "layers": 2, "length": 0.4, "width": 0.2, "segments": 40, "seed": 2}
    plain = swatch(**recipe).points.reshape(40, -1, 3).astype(np.float64)
    strayed = swatch(**recipe, strays=4, stray_lift=0.05).points.reshape(40, -1, 3).astype(np.float64)
    moved = np.flatnonzero(np.any(strayed != plain, axis=(1, 2)))
    assert len(moved) == 4 and np.all(moved < 20)  # four fibers of the front layer
    lift = strayed[moved, :, 2] - plain[moved, :, 2]
    assert np.all(np.diff(lift, axis=1) >= 0) and np.all(lift[:, 0] == 0)  # rising from the root on
    assert np.all((lift[:, -1] >= 0.025 - 1e-6) & (lift[:, -1] <= 0.05 + 1e-6))
    drift = np.abs(strayed[moved, -1, 0] - plain[moved, -1, 0])
    assert np.all(drift <= 0.5 * lift[:, -1] + 1e-6)
    assert np.all(lift[:, : int(0.75 * 40) + 1].min(axis=1) == 0)  # each leaves in its first three quarters
    # Over a drape, outward from the rod: the stray tips lie beyond every other fiber's distance from its axis.
    draped = swatch(**recipe, strays=4, drape=0.25).points.reshape(40, -1, 3).astype(np.float64)
    reach = np.hypot(draped[..., 1], draped[..., 2] + 0.25)
    others = np.setdiff1d(np.arange(40), moved)
    assert reach[moved, -1].min() > reach[others].max() + 0.4 * 0.04  # default lift: a tenth of the length


def test_a_thick_opaque_swatch_of_many_layers():
    """Twelve layers (the front ones hide the back ones), draped: each layer at its own depth, the gap between
    layers the default one; a swatch deeper than its rod is an error naming both."""
    fibers = swatch(count=456, layers=12, length=0.5, width=0.4, jitter=0.15, segments=16, seed=1)
    depths = [layer[..., 2].mean() for layer in layer_slices(fibers, 12)]
    spacing = 0.4 / 38
    np.testing.assert_allclose(np.diff(depths), -(2 * 0.004 + 0.15 * spacing), rtol=0.05)
    draped = swatch(count=456, layers=12, length=0.5, width=0.4, jitter=0.15, segments=16, seed=1, drape=0.25)
    assert draped.num_strands == 456
    with pytest.raises(ValueError, match=r"drape = 0.25 is smaller than the swatch's depth 0.39"):
        swatch(count=1200, layers=40, length=0.5, width=0.4, jitter=0.15, segments=4, drape=0.25)


@pytest.mark.parametrize(
    "keys, message",
    [
        ({"clumps": 1.5}, "clumps must be an integer, got 1.5"),
        ({"clumps": -1}, "clumps must be at least 0, got -1"),
        ({"clumps": 41}, "clumps must be at most the 40 fibers, got 41"),
        ({"clump_strength": 0.5}, r"clump_strength needs clumps \(the number of clumps, at least 1\)"),
        ({"clumps": 3, "clump_strength": 1.5}, r"clump_strength must be in \[0, 1\], got 1.5"),
        ({"strays": 21}, "strays must be at most the front layer's 20 fibers"),
        ({"strays": 2, "stray_lift": -0.1}, "stray_lift must be a positive finite number, got -0.1"),
        ({"stray_lift": 0.1}, "stray_lift needs strays"),
        ({"layer_phase_jitter": 1.5}, r"layer_phase_jitter must be in \[0, 1\], got 1.5"),
        ({"layer_shift_jitter": -0.2}, r"layer_shift_jitter must be in \[0, 1\], got -0.2"),
    ],
)
def test_bad_clumps_strays_and_layer_phases_name_the_key_in_the_scene(keys, message):
    fibers = {"generator": "wavy", "count": 40, "layers": 2, "length": 0.3, "segments": 8, **keys}
    light = {"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": [1.0, 1.0, 1.0]}
    data = {"camera": front_camera(0.3, (4, 4)), "lights": [light], "fibers": fibers, "hair": {"albedo": [0.5] * 3}}
    with pytest.raises(ValueError, match=r"\[fibers\] generator 'wavy': " + message):
        scene_from_dict(data)
