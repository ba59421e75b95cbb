"""Cubic curves (Bézier, B-spline, Catmull-Rom) as the polylines the renderer traces, within a stated distance.

    from warp_hair.geometry.curves import catmull_rom, tessellate
    fibers = catmull_rom(fibers)                         # strands as Catmull-Rom curves through their vertices
    points, params, values = tessellate(cv, "bspline", "nonperiodic", max_deviation=1e-5)

The renderer intersects straight tubes and shades them with a tangent that turns continuously
(`intersect.shading_frame`); a cubic curve becomes a polyline whose every point lies within `max_deviation` of
the curve, and whose vertices lie on it. Each span gets the fewest equal parameter steps that guarantee it: a
chord over a parameter step Δ stays within Δ²/8 · max |P''| of the arc it spans (linear interpolation's error,
which holds for vector-valued curves through its integral form), and P'' is linear on a cubic span, so its
largest norm is at one of the span's ends. With `max_deviation = tolerance × radius` (the default tolerance is
1% of the fiber's radius), the tube the renderer traces lies within that distance of the curve's tube: the ray
test is exact against the polyline and bounded against the curve; no ray test against the cubic itself.

Bases are the UsdGeom.BasisCurves schema's ("Cubic Basis"): P(t) = [t³ t² t 1] · M · [P0 P1 P2 P3]ᵀ for one
span, spans stepping over the control points by `VSTEP`; wrap `periodic` closes the curve, `pinned` adds phantom
ends (2p₀ − p₁) so that B-spline and Catmull-Rom curves end on their end points. `catmull_rom` repeats each
strand's end vertices instead, as Blender Cycles does for its curves (intern/cycles/bvh/embree.cpp,
`pack_motion_verts`: "Duplicate Embree's Catmull-Rom spline CVs at the start and end of each curve"), so that
warp-hair and Cycles render the same curve through a groom's vertices.
"""

from __future__ import annotations

import numpy as np

from .. import validate

# P(t) = [t³ t² t 1] · M · [P0 P1 P2 P3]ᵀ for one span (UsdGeom.BasisCurves schema, "Cubic Basis").
BASIS_MATRICES = {
    "bezier": np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]], dtype=np.float64),
    "bspline": np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]], dtype=np.float64) / 6.0,
    "catmullRom": np.array([[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]], dtype=np.float64) / 2.0,
}
# How far the first control point moves from one span to the next.
VSTEP = {"bezier": 3, "bspline": 1, "catmullRom": 1}
WRAPS = ("nonperiodic", "periodic", "pinned")
# The polyline's largest distance from the curve, as a fraction of the fiber's radius.
DEFAULT_TOLERANCE = 0.01
# A span is never cut finer than this: a bound that asks for more steps means a degenerate span or tolerance.
MAX_PIECES_PER_SPAN = 4096
# [6t 2 0 0] at t = 0 and t = 1: the rows that give P'' at a span's two ends.
_SECOND_DERIVATIVE_ENDS = np.array([[0.0, 2.0, 0.0, 0.0], [6.0, 2.0, 0.0, 0.0]])


def span_count(basis, wrap, n):
    """The number of cubic spans `n` control points make (0 when too few)."""
    if wrap == "periodic":
        return n // VSTEP[basis]
    if wrap == "pinned" and basis != "bezier":
        n += 2
    return (n - 4) // VSTEP[basis] + 1 if n >= 4 else 0


def control_points(cv, basis, wrap):
    """The control points the spans step over: periodic curves wrap around, pinned ones get phantom ends."""
    if wrap == "periodic":
        return np.concatenate([cv, cv[: 4 - VSTEP[basis]]])
    if wrap == "pinned" and basis != "bezier":
        return np.concatenate([2 * cv[:1] - cv[1:2], cv, 2 * cv[-1:] - cv[-2:-1]])
    return cv


def check_tolerance(tolerance):
    """`tolerance` as a float (a fraction of the fiber radius), or a ValueError naming it."""
    value = validate.real("tolerance", tolerance)
    if not value > 0:
        raise ValueError(f"tolerance must be a positive number (a fraction of the fiber radius), got {tolerance!r}")
    return value


def span_pieces(windows, basis, max_deviation):
    """(S,) the fewest equal parameter steps whose chords keep each span within `max_deviation` (a distance, one
    or (S,)) of the curve; `windows` (S, 4, 3) are the spans' control points (module docstring for the bound)."""
    second = np.einsum("ij,jk,skd->sid", _SECOND_DERIVATIVE_ENDS, BASIS_MATRICES[basis], windows)
    largest = np.linalg.norm(second, axis=2).max(axis=1)
    pieces = np.maximum(1.0, np.ceil(np.sqrt(largest / (8.0 * np.asarray(max_deviation, dtype=np.float64)))))
    worst = int(np.argmax(pieces))
    if pieces[worst] > MAX_PIECES_PER_SPAN:
        deviation = np.broadcast_to(max_deviation, pieces.shape)[worst]
        raise ValueError(
            f"a curve span would need {pieces[worst]:.0f} straight pieces to stay within {deviation:g} "
            f"of the curve (at most {MAX_PIECES_PER_SPAN}): raise the tolerance"
        )
    return pieces.astype(np.int64)


def _evaluate(windows, basis, pieces, closes, values=None):
    """The spans' points at t = 0, 1/n, …, (n − 1)/n, and t = 1 too where `closes` (a curve's last span):
    (points (N, 3), params (N,) = span index + t, values (N, k) or None), spans in order."""
    counts = pieces + closes
    span = np.repeat(np.arange(len(windows)), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(len(span)) - first[span]) / pieces[span]
    weights = np.stack([t**3, t**2, t, np.ones_like(t)], axis=1) @ BASIS_MATRICES[basis]  # (N, 4)
    points = np.einsum("nj,njd->nd", weights, windows[span])
    evaluated = None if values is None else np.einsum("nj,njd->nd", weights, values[span])
    return points, span + t, evaluated


def _windows(control, spans, step):
    """(spans, 4, ...) the control points of each span."""
    index = np.arange(spans)[:, None] * step + np.arange(4)[None, :]
    return control[index]


def tessellate(cv, basis, wrap, *, max_deviation=None, segments=None, values=None):
    """One cubic curve as a polyline: (points (N, 3), params (N,), values (N, k) or None).

    `max_deviation` (a distance) chooses each span's steps; `segments` instead gives every span that many.
    params are span index + t, for interpolating per-span data; `values` (per control point, e.g. widths) are
    evaluated with the curve's own basis."""
    if (max_deviation is None) == (segments is None):
        raise ValueError("give exactly one of max_deviation and segments")
    if basis not in BASIS_MATRICES or wrap not in WRAPS:
        raise ValueError(f"unsupported basis {basis!r} / wrap {wrap!r}")
    cv = np.asarray(cv, dtype=np.float64)
    spans = span_count(basis, wrap, len(cv))
    if spans < 1:
        raise ValueError(f"{len(cv)} control points are too few for a {wrap} {basis} curve")
    windows = _windows(control_points(cv, basis, wrap), spans, VSTEP[basis])
    extra = None
    if values is not None:
        extra = _windows(
            control_points(np.asarray(values, dtype=np.float64).reshape(len(cv), -1), basis, wrap), spans, VSTEP[basis]
        )
    pieces = (
        np.full(spans, segments, dtype=np.int64) if segments is not None else span_pieces(windows, basis, max_deviation)
    )
    closes = (np.arange(spans) == spans - 1).astype(np.int64)  # the last span keeps its end point
    return _evaluate(windows, basis, pieces, closes, extra)


def catmull_rom(fibers, tolerance=DEFAULT_TOLERANCE):
    """`fibers` with each strand replaced by the Catmull-Rom curve through its vertices (end vertices repeated,
    as Cycles draws them), tessellated to within `tolerance` × the strand's smallest radius; radii follow the
    same curve. A strand of two vertices stays the straight segment it is. All strands at once: a groom of a
    million vertices takes seconds."""
    from .assembly import FiberAssembly

    tolerance = check_tolerance(tolerance)
    offsets = np.asarray(fibers.strand_offsets, dtype=np.int64)
    counts = np.diff(offsets)
    points = np.asarray(fibers.points, dtype=np.float64)
    radii = np.asarray(fibers.radii, dtype=np.float64)
    # Span j of a strand runs from its vertex j to j + 1, with vertices j − 1 and j + 2 as the outer control
    # points, clamped to the strand: the end vertices repeated.
    strand = np.repeat(np.arange(len(counts)), counts - 1)
    j = np.arange(len(strand)) - np.concatenate([[0], np.cumsum(counts - 1)[:-1]])[strand]
    last = (counts[strand] - 1)[:, None]
    index = offsets[strand][:, None] + np.clip(j[:, None] + np.arange(-1, 3)[None, :], 0, last)
    smallest = np.minimum.reduceat(radii, offsets[:-1])
    pieces = span_pieces(points[index], "catmullRom", tolerance * smallest[strand])
    closes = (j == counts[strand] - 2).astype(np.int64)
    new_points, _, new_radii = _evaluate(points[index], "catmullRom", pieces, closes, radii[index][..., None])
    per_strand = np.bincount(strand, weights=pieces + closes, minlength=len(counts)).astype(np.int64)
    return FiberAssembly(
        new_points, new_radii[:, 0], np.concatenate([[0], np.cumsum(per_strand)]), strand_random=fibers.strand_random
    )
