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

import math

import numpy as np

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
        return np.concatenate([cv, cv[:4 - VSTEP[basis]]])
    if wrap == "pinned" and basis != "bezier":
        return np.concatenate([2 * cv[:1] - cv[1:2], cv, 2 * cv[-1:] - cv[-2:-1]])
    return cv


def span_pieces(window, basis, max_deviation):
    """The fewest equal parameter steps whose chords stay within `max_deviation` of this span (module doc)."""
    second = _SECOND_DERIVATIVE_ENDS @ BASIS_MATRICES[basis] @ window
    largest = float(np.max(np.linalg.norm(second, axis=1)))
    pieces = math.ceil(math.sqrt(largest / (8.0 * max_deviation))) if largest > 0.0 else 1
    if pieces > MAX_PIECES_PER_SPAN:
        raise ValueError(f"a curve span would need {pieces} straight pieces to stay within {max_deviation:g} of "
                         f"the curve (at most {MAX_PIECES_PER_SPAN}): raise the tolerance")
    return max(1, pieces)


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
    control = control_points(cv, basis, wrap)
    extra = None if values is None else control_points(np.asarray(values, dtype=np.float64).reshape(len(cv), -1),
                                                       basis, wrap)
    spans = span_count(basis, wrap, len(cv))
    if spans < 1:
        raise ValueError(f"{len(cv)} control points are too few for a {wrap} {basis} curve")
    step = VSTEP[basis]
    points, params, evaluated = [], [], []
    for span in range(spans):
        window = slice(span * step, span * step + 4)
        pieces = segments if segments is not None else span_pieces(control[window], basis, max_deviation)
        last = span == spans - 1
        t = np.arange(pieces + last) / pieces  # the last span keeps its end point
        weights = np.stack([t**3, t**2, t, np.ones_like(t)], axis=1) @ BASIS_MATRICES[basis]
        points.append(weights @ control[window])
        params.append(span + t)
        if extra is not None:
            evaluated.append(weights @ extra[window])
    return (np.concatenate(points), np.concatenate(params),
            None if extra is None else np.concatenate(evaluated))


def catmull_rom(fibers, tolerance=DEFAULT_TOLERANCE):
    """`fibers` with each strand replaced by the Catmull-Rom curve through its vertices (end vertices repeated,
    as Cycles draws them), tessellated to within `tolerance` × the strand's smallest radius; radii follow the
    same curve. A strand of two vertices stays the straight segment it is."""
    from .assembly import FiberAssembly

    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a positive number (a fraction of the fiber radius), got {tolerance!r}")
    strands = []
    for k in range(fibers.num_strands):
        points, radii = fibers.strand(k)
        cv = np.concatenate([points[:1], points, points[-1:]])
        cr = np.concatenate([radii[:1], radii, radii[-1:]])
        p, _, r = tessellate(cv, "catmullRom", "nonperiodic", max_deviation=tolerance * float(radii.min()),
                             values=cr)
        strands.append((p, r[:, 0]))
    return FiberAssembly.from_strands(strands)
