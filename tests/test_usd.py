"""USD BasisCurves in and out: stages written with usd-core's own API, polylines checked against each cubic
basis written here in its own form (Bernstein, uniform B-spline blending functions, Catmull-Rom as Hermite)."""

import sys

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is the `usd` extra")
from helpers.curves import FORMS, dense_curve, distance_to_polyline  # noqa: E402
from pxr import Gf, Usd, UsdGeom  # noqa: E402

from warp_hair.geometry.formats import load_fibers, save_fibers  # noqa: E402
from warp_hair.geometry.generators import swatch  # noqa: E402
from warp_hair.geometry.usd import UsdCurveError, read_usd  # noqa: E402
from warp_hair.scene import load_scene  # noqa: E402

RNG = np.random.default_rng(7)
SEGMENTS = 5


def expected_polyline(cv, basis, wrap, segments=SEGMENTS):
    """The polyline: each span of the curve at t = 0, 1/segments, ... and the last span's end."""
    form, step = FORMS[basis]
    n = len(cv)
    if wrap == "periodic":
        spans = n // step
        window = lambda i: [cv[(i * step + j) % n] for j in range(4)]  # noqa: E731
    else:
        if wrap == "pinned" and basis != "bezier":
            cv = np.concatenate([[2 * cv[0] - cv[1]], cv, [2 * cv[-1] - cv[-2]]])
        spans = (len(cv) - 4) // step + 1
        window = lambda i: cv[i * step : i * step + 4]  # noqa: E731
    points = [form(window(i), t) for i in range(spans) for t in np.arange(segments) / segments]
    return np.array([*points, form(window(spans - 1), 1.0)])


def write_stage(
    path,
    curves,
    *,
    basis="bspline",
    kind="cubic",
    wrap="nonperiodic",
    widths=None,
    interpolation="vertex",
    transform=None,
    prim="/Groom/hair",
):
    stage = Usd.Stage.CreateNew(str(path))
    xform = UsdGeom.Xform.Define(stage, "/Groom")
    if transform is not None:
        translate, scale = transform
        xform.AddTranslateOp().Set(Gf.Vec3d(*translate))
        xform.AddScaleOp().Set(Gf.Vec3f(scale, scale, scale))
    c = UsdGeom.BasisCurves.Define(stage, prim)
    c.CreateTypeAttr(kind)
    c.CreateBasisAttr(basis)
    c.CreateWrapAttr(wrap)
    c.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for cv in curves for p in cv])
    c.CreateCurveVertexCountsAttr([len(cv) for cv in curves])
    if widths is not None:
        c.CreateWidthsAttr([float(w) for w in widths])
        c.SetWidthsInterpolation(interpolation)
    stage.GetRootLayer().Save()
    return path


def control_points(count, n):
    return [np.cumsum(RNG.normal(size=(n, 3)), axis=0).astype(np.float32).astype(np.float64) for _ in range(count)]


@pytest.mark.parametrize("basis", list(FORMS))
@pytest.mark.parametrize("wrap", ["nonperiodic", "periodic", "pinned"])
def test_cubic_curves_follow_their_basis(tmp_path, basis, wrap):
    # Bezier spans share end points: 3k + 1 control points for k spans, 3k when periodic.
    n = 7 if basis == "bezier" and wrap != "periodic" else 6
    curves = control_points(2, n)
    path = write_stage(tmp_path / "groom.usda", curves, basis=basis, wrap=wrap, widths=[0.01], interpolation="constant")
    fibers = read_usd(path, segments=SEGMENTS)
    assert fibers.num_strands == 2
    for k, cv in enumerate(curves):
        points, radii = fibers.strand(k)
        np.testing.assert_allclose(points, expected_polyline(cv, basis, wrap), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(radii, 0.005, rtol=1e-6)


@pytest.mark.parametrize("basis", list(FORMS))
def test_cubic_curves_are_traced_within_the_tolerance(tmp_path, basis):
    """Without `segments`, each span is cut finely enough that the polyline stays within tolerance × radius."""
    (cv,) = control_points(1, 7 if basis == "bezier" else 6)
    path = write_stage(tmp_path / "g.usda", [cv], basis=basis, widths=[0.02], interpolation="constant")
    for tolerance in (None, 0.05):
        fibers = read_usd(path) if tolerance is None else read_usd(path, tolerance=tolerance)
        points, _ = fibers.strand(0)
        allowed = (tolerance or 0.01) * 0.01  # radius 0.01
        assert distance_to_polyline(dense_curve(cv, basis), points.astype(np.float64)).max() <= allowed * 1.01
    with pytest.raises(UsdCurveError, match="give tolerance or segments, not both"):
        read_usd(path, tolerance=0.01, segments=4)
    with pytest.raises(UsdCurveError, match=r"/Groom/hair: curve 0: a curve span would need \d+ straight pieces"):
        read_usd(path, tolerance=1e-12)
    with pytest.raises(UsdCurveError, match="tolerance must be a positive number"):
        read_usd(path, tolerance=-0.01)


def test_pinned_curves_end_on_their_end_points(tmp_path):
    (cv,) = control_points(1, 5)
    for basis in ("bspline", "catmullRom"):
        fibers = read_usd(
            write_stage(
                tmp_path / f"{basis}.usda", [cv], basis=basis, wrap="pinned", widths=[0.01], interpolation="constant"
            )
        )
        points, _ = fibers.strand(0)
        np.testing.assert_allclose(points[[0, -1]], cv[[0, -1]], atol=1e-5)


def test_linear_curves_keep_vertices_and_halve_widths(tmp_path):
    curves = control_points(3, 4)
    widths = RNG.uniform(0.005, 0.02, size=12)
    fibers = read_usd(write_stage(tmp_path / "g.usda", curves, kind="linear", widths=widths))
    np.testing.assert_allclose(fibers.points, np.concatenate(curves), rtol=1e-6)
    np.testing.assert_allclose(fibers.radii, widths / 2, rtol=1e-6)
    closed = read_usd(
        write_stage(
            tmp_path / "p.usda",
            curves,
            kind="linear",
            wrap="periodic",
            widths=[0.01, 0.02, 0.03],
            interpolation="uniform",
        )
    )
    assert list(closed.vertex_counts) == [5, 5, 5]
    np.testing.assert_allclose(closed.strand(1)[0][-1], curves[1][0], rtol=1e-6)
    np.testing.assert_allclose(closed.strand(2)[1], 0.015, rtol=1e-6)


def test_vertex_and_varying_widths_on_cubic_curves(tmp_path):
    (cv,) = control_points(1, 6)  # a bspline of 3 spans
    widths = np.array([0.01, 0.02, 0.04, 0.02, 0.01, 0.03])
    fibers = read_usd(write_stage(tmp_path / "v.usda", [cv], widths=widths), segments=SEGMENTS)
    # Vertex widths are interpolated with the curve's basis.
    np.testing.assert_allclose(
        fibers.radii, expected_polyline(widths[:, None], "bspline", "nonperiodic")[:, 0] / 2, rtol=1e-5
    )
    ends = np.array([0.01, 0.03, 0.02, 0.04])  # varying: one per span end
    fibers = read_usd(write_stage(tmp_path / "y.usda", [cv], widths=ends, interpolation="varying"), segments=SEGMENTS)
    np.testing.assert_allclose(
        fibers.radii, np.interp(np.arange(3 * SEGMENTS + 1) / SEGMENTS, np.arange(4), ends) / 2, rtol=1e-6
    )


def test_transform_applied_to_points_and_widths(tmp_path):
    curves = control_points(2, 3)
    fibers = read_usd(
        write_stage(
            tmp_path / "t.usda",
            curves,
            kind="linear",
            widths=[0.01, 0.02],
            interpolation="uniform",
            transform=((1.0, -2.0, 0.5), 2.0),
        )
    )
    np.testing.assert_allclose(fibers.points, 2.0 * np.concatenate(curves) + [1.0, -2.0, 0.5], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(fibers.radii, np.repeat([0.01, 0.02], 3), rtol=1e-6)  # 2 × width / 2


def test_prim_selection_and_radius_for_missing_widths(tmp_path):
    path = tmp_path / "two.usda"
    stage = Usd.Stage.CreateNew(str(path))
    for name, n in (("/Groom/hair", 3), ("/Groom/guides", 2)):
        c = UsdGeom.BasisCurves.Define(stage, name)
        c.CreateTypeAttr("linear")
        c.CreatePointsAttr([Gf.Vec3f(float(i), float(n), 0.0) for i in range(n)])
        c.CreateCurveVertexCountsAttr([n])
    stage.GetRootLayer().Save()
    with pytest.raises(UsdCurveError, match=r"two.usda: /Groom/(hair|guides): has no widths; give the fibers a radius"):
        read_usd(path)
    both = read_usd(path, radius=0.01)
    assert both.num_strands == 2 and np.all(both.radii == np.float32(0.01))
    assert list(read_usd(path, prim="/Groom/hair", radius=0.01).vertex_counts) == [3]
    with pytest.raises(UsdCurveError, match="no prim at '/Nope'"):
        read_usd(path, prim="/Nope", radius=0.01)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda c: c.GetCurveVertexCountsAttr().Set([2, 2]), "curveVertexCounts add up to 4, but there are 3 points"),
        (
            lambda c: c.GetPointsAttr().Set([Gf.Vec3f(0, 0, 0), Gf.Vec3f(float("nan"), 0, 0), Gf.Vec3f(1, 1, 1)]),
            "point 1 .* is not finite",
        ),
        (lambda c: c.GetWidthsAttr().Set([0.1, 0.1]), "has 2 widths; vertex widths need 3"),
        (lambda c: c.GetWidthsAttr().Set([0.1, -0.1, 0.1]), "width -0.1 .* is not a positive number"),
        (
            lambda c: (c.GetTypeAttr().Set("cubic"), c.GetBasisAttr().Set("bspline")),
            "curve 0 has 3 control points, too few",
        ),
    ],
)
def test_bad_curves_name_file_and_prim(tmp_path, edit, message):
    path = write_stage(
        tmp_path / "bad.usda", [np.zeros((3, 3)) + np.arange(3)[:, None]], kind="linear", widths=[0.1, 0.1, 0.1]
    )
    stage = Usd.Stage.Open(str(path))
    edit(UsdGeom.BasisCurves(stage.GetPrimAtPath("/Groom/hair")))
    stage.GetRootLayer().Save()
    with pytest.raises(UsdCurveError, match=f"bad.usda: /Groom/hair: {message}"):
        load_fibers(path)


def test_unreadable_stage_and_bad_options(tmp_path):
    path = tmp_path / "junk.usda"
    path.write_text('#usda 1.0\ndef Xform "oops" {{{\n')
    with pytest.raises(UsdCurveError, match=r"junk.usda: cannot open the USD stage"):
        load_fibers(path)
    with pytest.raises(UsdCurveError, match="radius must be a positive number, got 'thin'"):
        load_fibers(path, radius="thin")
    with pytest.raises(UsdCurveError, match="segments must be an integer >= 1, got 0"):
        load_fibers(path, segments=0)


def test_no_basis_curves(tmp_path):
    path = tmp_path / "empty.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    stage.GetRootLayer().Save()
    with pytest.raises(UsdCurveError, match=r"empty.usda: no .*BasisCurves prim under the stage"):
        load_fibers(path)


def test_round_trip_text_usd_text_keeps_every_vertex(tmp_path):
    text = tmp_path / "a.txt"
    save_fibers(swatch(count=12, segments=7, seed=3), text)
    original = load_fibers(text)
    for suffix in (".usda", ".usdc"):
        save_fibers(swatch(count=4), tmp_path / f"groom{suffix}")  # replaced by the next save
        save_fibers(original, tmp_path / f"groom{suffix}")
        back = tmp_path / f"back{suffix}.txt"
        save_fibers(load_fibers(tmp_path / f"groom{suffix}"), back)
        again = load_fibers(back)
        assert np.array_equal(again.points, original.points)
        assert np.array_equal(again.radii, original.radii)
        assert np.array_equal(again.strand_offsets, original.strand_offsets)


def test_scene_file_reads_a_groom(tmp_path):
    curves = control_points(2, 6)
    write_stage(tmp_path / "groom.usda", curves, widths=None)
    scene = tmp_path / "scene.toml"
    body = (
        '[camera]\ntype = "orthographic"\norigin = [0, 0, 5]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nwidth = 2.0\n'
        'resolution = [8, 8]\n[[lights]]\ntype = "environment"\nradiance = [1, 1, 1]\n'
        '[fibers]\nfile = "groom.usda"\nprim = "/Groom/hair"\nradius = 0.01\nsegments = 3\n[hair]\nalbedo = 0.5\n'
    )
    scene.write_text(body)
    fibers = load_scene(scene).fibers
    assert list(fibers.vertex_counts) == [3 * 3 + 1] * 2
    scene.write_text(body.replace("segments = 3", "segment = 3"))
    with pytest.raises(ValueError, match=r"\[fibers\] unknown key\(s\) \['segment'\]"):
        load_scene(scene)


def test_options_are_for_usd_only_and_missing_usd_core_names_the_extra(tmp_path, monkeypatch):
    text = tmp_path / "a.txt"
    save_fibers(swatch(count=4), text)
    with pytest.raises(ValueError, match="radius apply to USD files only"):
        load_fibers(text, radius=0.1)
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(ImportError, match=r"install the `usd` extra"):
        load_fibers(tmp_path / "groom.usda")
