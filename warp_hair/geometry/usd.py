"""USD grooms: `UsdGeom.BasisCurves` in and out (needs the `usd` extra: `pip install -e ".[usd]"`, usd-core).

    from warp_hair.geometry import load_fibers, save_fibers
    fibers = load_fibers("groom.usda")                              # every BasisCurves prim on the stage
    fibers = load_fibers("groom.usd", prim="/Groom/hair", radius=0.004, tolerance=0.01)
    save_fibers(fibers, "groom.usdc")                               # one linear BasisCurves prim, /Groom/hair

and in a scene file:

    [fibers]
    file = "groom.usda"
    prim = "/Groom/hair"      # optional: this prim and the BasisCurves under it (default: the whole stage)
    radius = 0.004            # optional: the radius of curves without widths (widths win where present)
    tolerance = 0.01          # optional: how far the traced polyline may stray from a cubic curve, in radii
    segments = 8              # optional, instead of tolerance: straight pieces per cubic span

Reading: every active, visible BasisCurves prim under the stage's root (or under `prim`), except those of purpose
"guide", at the earliest authored time sample. Points go through the prim's local-to-world transform; widths are
diameters (`constant`, `uniform` = one per curve, `varying` = one per span end, `vertex` = one per control point)
and become radii, scaled by the transform's mean scale (the cube root of its determinant). Linear curves keep their
vertices (periodic ones close on their first). Cubic curves (`bezier`, `bspline`, `catmullRom`; wrap `nonperiodic`,
`periodic`, or `pinned`, whose phantom end points make B-spline and Catmull-Rom curves end on their end points) are
traced as polylines within `tolerance` × the curve's smallest radius of the true curve (default 1%; each span cut
into the fewest equal parameter steps that guarantee it, `warp_hair.geometry.curves`), or at `segments` evenly
spaced parameters per span when that is given; `vertex` widths are interpolated with the curve's basis,
`varying` ones linearly within each span. Strands are
listed root first, as the fibers' convention is.

A `random` primvar (one float in [0, 1] per curve) gives each strand its random value for the variation's
controls (`color_spread`, `roughness_spread`; model/variation.py); without one a strand's comes from its index, as
Cycles draws a curve's. `save_fibers` writes it where the fibers have their own.

Errors name the file and the prim: no BasisCurves found, vertex counts that do not add up to the points, curves
with too few control points for their basis, non-finite points, widths of the wrong length, missing widths
without `radius`.
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path

import numpy as np

from .curves import BASIS_MATRICES, DEFAULT_TOLERANCE, WRAPS, check_tolerance, span_count, tessellate

SUFFIXES = (".usd", ".usda", ".usdc")
WRITE_PRIM = "/Groom/hair"
RANDOM_PRIMVAR = "random"  # each strand's random value for the variation's controls


class UsdCurveError(ValueError):
    """A problem with a USD groom, naming the file and (where known) the prim."""

    def __init__(self, path, problem, prim=None):
        where = f"{path}" + (f": {prim}" if prim else "")
        super().__init__(f"{where}: {problem}")


def _pxr(path):
    try:
        from pxr import Usd, UsdGeom
    except ImportError:
        raise ImportError(
            f'{path}: reading and writing USD needs usd-core: install the `usd` extra (pip install -e ".[usd]")'
        ) from None
    return Usd, UsdGeom


def read_usd(path, *, prim=None, radius=None, tolerance=None, segments=None):
    """A FiberAssembly from the BasisCurves of a USD stage (see the module docstring)."""
    from .assembly import FiberAssembly, FiberDataError

    path = Path(path)
    Usd, UsdGeom = _pxr(path)
    if segments is not None and (not isinstance(segments, int) or isinstance(segments, bool) or segments < 1):
        raise UsdCurveError(path, f"segments must be an integer >= 1, got {segments!r}")
    if tolerance is not None and segments is not None:
        raise UsdCurveError(path, "give tolerance or segments, not both")
    if segments is None:
        try:
            tolerance = check_tolerance(DEFAULT_TOLERANCE if tolerance is None else tolerance)
        except ValueError as error:
            raise UsdCurveError(path, str(error)) from None
    real = isinstance(radius, numbers.Real) and not isinstance(radius, bool)
    if radius is not None and not (real and math.isfinite(radius) and radius > 0):
        raise UsdCurveError(path, f"radius must be a positive number, got {radius!r}")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: USD file not found")
    try:
        stage = Usd.Stage.Open(str(path))
    except RuntimeError as error:  # pxr.Tf.ErrorException: not a USD file, or a malformed one
        raise UsdCurveError(path, f"cannot open the USD stage: {str(error).strip()}") from None
    if stage is None:
        raise UsdCurveError(path, "cannot open the USD stage")
    if prim is None:
        start = stage.GetPseudoRoot()
    else:
        start = stage.GetPrimAtPath(prim) if isinstance(prim, str) and prim.startswith("/") else None
        if start is None or not start.IsValid():
            raise UsdCurveError(path, f'no prim at {prim!r} (give an absolute prim path, e.g. "/Groom/hair")')
    strands = []
    randoms = {}  # prim path → its curves' random values (a `random` primvar), or None
    found = 0
    for node in Usd.PrimRange(start):
        if not node.IsA(UsdGeom.BasisCurves):
            continue
        imageable = UsdGeom.Imageable(node)
        if (
            imageable.ComputeVisibility() == UsdGeom.Tokens.invisible
            or imageable.ComputePurpose() == UsdGeom.Tokens.guide
        ):
            continue
        found += 1
        curves = UsdGeom.BasisCurves(node)
        new = list(_curves(path, curves, Usd, UsdGeom, radius, tolerance, segments))
        strands.extend(new)
        randoms[str(node.GetPath())] = _random(path, curves, Usd, UsdGeom, len(new))
    if not found:
        under = "the stage" if prim is None else repr(prim)
        raise UsdCurveError(path, f"no (visible, non-guide) BasisCurves prim under {under}")
    given = [name for name, values in randoms.items() if values is not None]
    if given and len(given) != len(randoms):
        missing = next(name for name, values in randoms.items() if values is None)
        raise UsdCurveError(path, f"{given[0]} has a random primvar and {missing} has none: give all or none")
    strand_random = np.concatenate(list(randoms.values())) if given else None
    try:
        return FiberAssembly.from_strands(strands, strand_random=strand_random, source=path)
    except FiberDataError as error:
        raise UsdCurveError(path, str(error).removeprefix(f"{path}: ")) from None


def _get(attribute, Usd):
    return attribute.Get(Usd.TimeCode.EarliestTime()) if attribute else None


def _curves(path, curves, Usd, UsdGeom, radius, tolerance, segments):
    name = str(curves.GetPath())
    fail = lambda problem: UsdCurveError(path, problem, name)  # noqa: E731
    points = _get(curves.GetPointsAttr(), Usd)
    counts = _get(curves.GetCurveVertexCountsAttr(), Usd)
    if points is None or counts is None:
        raise fail("needs points and curveVertexCounts")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts, dtype=np.int64).reshape(-1)
    if np.any(counts < 0) or counts.sum() != len(points):
        raise fail(f"curveVertexCounts add up to {int(counts.sum())}, but there are {len(points)} points")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise fail(f"point {int(bad[0])} ({', '.join(f'{x:g}' for x in points[bad[0]])}) is not finite")
    kind = _get(curves.GetTypeAttr(), Usd) or "cubic"
    basis = _get(curves.GetBasisAttr(), Usd) or "bezier"
    wrap = _get(curves.GetWrapAttr(), Usd) or "nonperiodic"
    if kind not in ("linear", "cubic") or basis not in BASIS_MATRICES or wrap not in WRAPS:
        raise fail(f"unsupported curve type {kind!r} / basis {basis!r} / wrap {wrap!r}")

    matrix = np.array(
        UsdGeom.Xformable(curves.GetPrim()).ComputeLocalToWorldTransform(Usd.TimeCode.EarliestTime()), dtype=np.float64
    )
    # USD transforms row vectors: p_world = [p 1] · M.
    world = points @ matrix[:3, :3] + matrix[3, :3]
    scale = abs(np.linalg.det(matrix[:3, :3])) ** (1.0 / 3.0)

    widths = _get(curves.GetWidthsAttr(), Usd)
    interpolation = curves.GetWidthsInterpolation() if widths is not None else None
    if widths is None or len(widths) == 0:
        if radius is None:
            raise fail("has no widths; give the fibers a radius (radius = ... in the scene's [fibers] table)")
        widths, interpolation = np.array([2.0 * radius / scale]), "constant"
    widths = np.asarray(widths, dtype=np.float64).reshape(-1)
    bad = np.flatnonzero(~(np.isfinite(widths) & (widths > 0)))
    if bad.size:
        raise fail(f"width {widths[bad[0]]:g} (index {int(bad[0])}) is not a positive number")

    starts = np.concatenate([[0], np.cumsum(counts)])
    spans = [_span_count(kind, basis, wrap, int(n)) for n in counts]
    for k, (n, s) in enumerate(zip(counts, spans)):
        if s < 1:
            raise fail(
                f"curve {k} has {int(n)} control points, too few for a {wrap} {kind} "
                f"{basis if kind == 'cubic' else ''} curve".replace("  ", " ")
            )
    expected = {
        "constant": 1,
        "uniform": len(counts),
        "vertex": len(points),
        "varying": sum(s + (0 if wrap == "periodic" else 1) for s in spans),
    }
    expected["faceVarying"] = expected["varying"]
    if interpolation not in expected:
        raise fail(f"unsupported widths interpolation {interpolation!r}")
    if len(widths) != expected[interpolation]:
        raise fail(f"has {len(widths)} widths; {interpolation} widths need {expected[interpolation]}")

    varying_start = 0
    for k in range(len(counts)):
        cv = world[starts[k] : starts[k + 1]]
        if interpolation == "constant":
            cv_width = np.full(len(cv), widths[0])
        elif interpolation == "uniform":
            cv_width = np.full(len(cv), widths[k])
        elif interpolation == "vertex":
            cv_width = widths[starts[k] : starts[k + 1]]
        else:
            cv_width = None
        if kind == "linear":
            p, w = cv, cv_width
            if wrap == "periodic":
                p = np.concatenate([p, p[:1]])
                w = None if w is None else np.concatenate([w, w[:1]])
            if w is None:
                count = spans[k] + (0 if wrap == "periodic" else 1)
                w = widths[varying_start : varying_start + count]
                w = np.concatenate([w, w[:1]]) if wrap == "periodic" else w
        else:
            count = spans[k] + (0 if wrap == "periodic" else 1)
            ends = widths[varying_start : varying_start + count]
            smallest = cv_width.min() if cv_width is not None else ends.min()
            deviation = None if segments is not None else tolerance * 0.5 * scale * smallest
            try:
                p, params, w = tessellate(cv, basis, wrap, max_deviation=deviation, segments=segments, values=cv_width)
            except ValueError as error:  # a span that would need more pieces than a span may have
                raise fail(f"curve {k}: {error}") from None
            if w is None:
                ends = np.concatenate([ends, ends[:1]]) if wrap == "periodic" else ends
                w = np.interp(params, np.arange(len(ends)), ends)
            else:
                w = w[:, 0]
        varying_start += spans[k] + (0 if wrap == "periodic" else 1)
        yield p, 0.5 * scale * np.asarray(w)


def _random(path, curves, Usd, UsdGeom, count):
    """The curves' `random` primvar (one value in [0, 1] per curve, or one for all), or None where there is none:
    each strand's random value for the variation's controls (model/variation.py)."""
    primvar = UsdGeom.PrimvarsAPI(curves.GetPrim()).GetPrimvar(RANDOM_PRIMVAR)
    if not primvar or not primvar.HasAuthoredValue():
        return None
    fail = lambda problem: UsdCurveError(path, problem, str(curves.GetPath()))  # noqa: E731
    values = np.asarray(primvar.Get(Usd.TimeCode.EarliestTime()), dtype=np.float64).reshape(-1)
    interpolation = primvar.GetInterpolation()
    if interpolation not in ("constant", "uniform") or len(values) != (1 if interpolation == "constant" else count):
        raise fail(
            f"primvars:{RANDOM_PRIMVAR} must hold one value per curve (uniform, {count}) or one (constant); got "
            f"{len(values)} {interpolation}"
        )
    bad = np.flatnonzero(~((values >= 0.0) & (values <= 1.0)))
    if bad.size:
        raise fail(f"primvars:{RANDOM_PRIMVAR} value {values[bad[0]]:g} (curve {int(bad[0])}) is outside [0, 1]")
    return np.broadcast_to(values, count).astype(np.float32)


def _span_count(kind, basis, wrap, n):
    if kind == "linear":
        return n if wrap == "periodic" else n - 1
    return span_count(basis, wrap, n)


def write_usd(assembly, path, *, prim=WRITE_PRIM):
    """Save `assembly` as one linear, nonperiodic BasisCurves prim with per-vertex widths (2 × radius)."""
    path = Path(path)
    Usd, UsdGeom = _pxr(path)
    from pxr import Sdf, Vt

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    parent = prim.rsplit("/", 1)[0]
    if parent:
        UsdGeom.Xform.Define(stage, parent)
        stage.SetDefaultPrim(stage.GetPrimAtPath(parent))
    curves = UsdGeom.BasisCurves.Define(stage, prim)
    curves.CreateTypeAttr(UsdGeom.Tokens.linear)
    curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(assembly.points, dtype=np.float32)))
    curves.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(assembly.vertex_counts.astype(np.int32)))
    curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(2.0 * np.asarray(assembly.radii, dtype=np.float32)))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    if assembly.strand_random is not None:
        UsdGeom.PrimvarsAPI(curves.GetPrim()).CreatePrimvar(
            RANDOM_PRIMVAR, Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.uniform
        ).Set(Vt.FloatArray.FromNumpy(np.ascontiguousarray(assembly.strand_random, dtype=np.float32)))
    # Export (not CreateNew + Save) so that an existing file is replaced, as the other fiber writers do.
    try:
        written = stage.GetRootLayer().Export(str(path))
    except RuntimeError as error:  # pxr.Tf.ErrorException
        raise OSError(f"{path}: cannot write the USD file: {error}") from None
    if not written:
        raise OSError(f"{path}: cannot write the USD file")
