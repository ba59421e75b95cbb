"""Which strands pass through each other: the scene check behind the warning that renderers disagree there.

    report = interpenetration(assembly)     # InterpenetrationReport: pairs, strands, deepest overlap
    print(report.message("enter"))
    warn_interpenetration(assembly, "enter")  # an InterpenetrationWarning, once per assembly, if any

Two strands interpenetrate when a segment of one comes closer to a segment of the other than the sum of their
tube radii (each segment's tube has radius (r0 + r1) / 2, as `warp_hair.geometry.tubes` builds it; the test is
on the segments' axes, so near a strand's open end it counts the round cap a capsule would have, an
overestimate of at most one radius along the strand). Segments of one strand never count against each other.

Why it matters: a ray that starts inside another strand's tube (a path leaving a fiber that lies inside its
neighbour) is where renderers part. warp-hair (by default) and Mitsuba 3 count only the hits where a ray enters
a tube; Cycles 4.x on the CPU (Embree 4's round Catmull-Rom curves report exit hits too) also scatters where
the ray leaves the neighbour. docs/scenes.md, "Interpenetrating strands", has the sources and the measured
difference, and `[render] interpenetration` the choice. Loading or preparing a scene whose strands
interpenetrate warns once (`warn_interpenetration`), so that whoever compares with another renderer knows.

The candidates come from Warp's BVH over the segments' boxes (`wp.Bvh`, `wp.bvh_query_aabb`), the distances
from one kernel thread per segment, launched over all cores (`warp_hair.parallel`); each segment keeps the
distinct strands it overlaps in a few slots, and the few segments that overlap more strands go round again with
more. docs/scenes.md gives timings.
"""

from __future__ import annotations

import dataclasses
import warnings
import weakref

import numpy as np
import warp as wp

from ..parallel import launch_ranges

wp.set_module_options({"enable_backward": False})

# Axes closer than (r_a + r_b)·(1 − TOUCH) overlap: strands laid exactly side by side (distance r_a + r_b, as
# float32 rounds it) touch without passing through each other.
TOUCH = 1.0e-4


class InterpenetrationWarning(UserWarning):
    """The scene's strands pass through each other, where renderers disagree (see the module docstring)."""


@dataclasses.dataclass(frozen=True)
class InterpenetrationReport:
    """What `interpenetration` found. `pairs`: strand pairs that interpenetrate; `strands`: strands in at least
    one such pair; `segment_pairs`: segment pairs (of different strands) that overlap; `deepest`: the largest
    overlap, 1 − distance / (r_a + r_b), 0 when none (1 is two axes that cross); `num_strands`: of the
    assembly."""

    pairs: int
    strands: int
    segment_pairs: int
    deepest: float
    num_strands: int

    def message(self, rule: str = "enter") -> str:
        """One line for the user; `rule` is the scene's `[render] interpenetration`."""
        if self.pairs == 0:
            return f"no two of the {self.num_strands} strands interpenetrate"
        how = (
            "only the hits where a ray enters a tube count, as in Mitsuba 3"
            if rule == "enter"
            else "a ray that starts inside another strand's tube also scatters where it leaves it, as in Cycles 4.x "
            "on the CPU"
        )
        return (
            f"{self.pairs} pairs of strands interpenetrate ({self.strands} of {self.num_strands} strands; the "
            f"deepest overlap is {self.deepest:.0%} of the two radii): renderers disagree there. Here {how} "
            f'([render] interpenetration = "{rule}"; docs/scenes.md, "Interpenetrating strands")'
        )


@wp.func
def segment_distance_sq(p0: wp.vec3, p1: wp.vec3, q0: wp.vec3, q1: wp.vec3):
    """Squared distance between the segments p0p1 and q0q1: the closest pair of parameters (s, t) in [0, 1]²,
    clamping s, then t, then s again (the minimum of a convex quadratic over the square lies on the edge the
    unconstrained one is clamped to)."""
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    c = wp.dot(d1, r)
    b = wp.dot(d1, d2)
    s = float(0.0)
    t = float(0.0)
    if a > 0.0 and e > 0.0:
        den = a * e - b * b
        if den > 0.0:
            s = wp.clamp((b * f - c * e) / den, 0.0, 1.0)
        t = (b * s + f) / e
        if t < 0.0:
            t = 0.0
            s = wp.clamp(-c / a, 0.0, 1.0)
        elif t > 1.0:
            t = 1.0
            s = wp.clamp((b - c) / a, 0.0, 1.0)
    elif a > 0.0:
        s = wp.clamp(-c / a, 0.0, 1.0)
    elif e > 0.0:
        t = wp.clamp(f / e, 0.0, 1.0)
    g = (p0 + s * d1) - (q0 + t * d2)
    return wp.dot(g, g)


@wp.kernel
def _overlaps(
    bvh: wp.uint64,
    p0: wp.array(dtype=wp.vec3),
    p1: wp.array(dtype=wp.vec3),
    radius: wp.array(dtype=float),
    strand: wp.array(dtype=wp.int32),
    lowers: wp.array(dtype=wp.vec3),
    uppers: wp.array(dtype=wp.vec3),
    segments: wp.array(dtype=wp.int32),
    slots: int,
    partners: wp.array2d(dtype=wp.int32),
    overflow: wp.array(dtype=wp.int32),
    pairs: wp.array(dtype=wp.int32),
    depth: wp.array(dtype=float),
    first: int,
):
    """For segment segments[k]: the overlapping segments j > i of other strands, counted (pairs), the deepest
    overlap, and up to `slots` distinct strands among them (partners[k], −1 where unused; overflow[k] = 1 if
    there are more)."""
    k = wp.tid() + first
    i = segments[k]
    query = wp.bvh_query_aabb(bvh, lowers[i], uppers[i])
    j = int(0)
    n = int(0)
    used = int(0)
    deepest = float(0.0)
    while wp.bvh_query_next(query, j):
        if j > i and strand[j] != strand[i]:
            reach = radius[i] + radius[j]
            d2 = segment_distance_sq(p0[i], p1[i], p0[j], p1[j])
            limit = reach * (1.0 - TOUCH)
            if d2 < limit * limit:
                n += 1
                deepest = wp.max(deepest, 1.0 - wp.sqrt(d2) / reach)
                seen = int(0)
                for q in range(used):
                    if partners[k, q] == strand[j]:
                        seen = 1
                if seen == 0:
                    if used < slots:
                        partners[k, used] = strand[j]
                        used += 1
                    else:
                        overflow[k] = 1
    pairs[k] = n
    depth[k] = deepest


@wp.kernel
def _inside_other(
    bvh: wp.uint64,
    p0: wp.array(dtype=wp.vec3),
    p1: wp.array(dtype=wp.vec3),
    radius: wp.array(dtype=float),
    strand: wp.array(dtype=wp.int32),
    points: wp.array(dtype=wp.vec3),
    own: wp.array(dtype=wp.int32),
    inside: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    p = points[k]
    query = wp.bvh_query_aabb(bvh, p, p)
    j = int(0)
    while wp.bvh_query_next(query, j):
        if strand[j] != own[k]:
            r = radius[j] * (1.0 - TOUCH)
            if segment_distance_sq(p, p, p0[j], p1[j]) < r * r:
                inside[k] = 1


def _segment_arrays(assembly):
    """Device arrays of the segments (p0, p1, lower and upper box corners), their tube radii and strands."""
    p0, p1, r0, r1, strand, _ = assembly.segments()
    radius = (0.5 * (r0.astype(np.float64) + r1)).astype(np.float32)
    lo = (np.minimum(p0, p1) - radius[:, None]).astype(np.float32)
    hi = (np.maximum(p0, p1) + radius[:, None]).astype(np.float32)
    vectors = [wp.array(a, dtype=wp.vec3) for a in (p0, p1, lo, hi)]
    return vectors, wp.array(radius, dtype=float), wp.array(strand, dtype=wp.int32), strand


def points_inside_other_strands(assembly, points, strands, device: str = "cpu") -> np.ndarray:
    """(N,) bool: whether each of `points` (N, 3) lies inside a tube of a strand other than `strands` (N,) (its
    own, −1 for none): where a path vertex on that strand starts its rays inside another strand's tube."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    own = np.broadcast_to(np.asarray(strands, dtype=np.int32), len(points))
    with wp.ScopedDevice(device):
        (p0, p1, lo, hi), radius, strand, _ = _segment_arrays(assembly)
        bvh = wp.Bvh(lo, hi)
        inside = wp.zeros(len(points), dtype=wp.int32)
        wp.launch(
            _inside_other,
            dim=len(points),
            inputs=[
                bvh.id,
                p0,
                p1,
                radius,
                strand,
                wp.array(points, dtype=wp.vec3),
                wp.array(own, dtype=wp.int32),
                inside,
            ],
        )
        return inside.numpy().astype(bool)


def interpenetration(assembly, device: str = "cpu") -> InterpenetrationReport:
    """Count the pairs of strands of `assembly` (a `FiberAssembly`) that pass through each other."""
    m = assembly.num_segments
    if m == 0 or assembly.num_strands < 2:
        return InterpenetrationReport(0, 0, 0, 0.0, assembly.num_strands)
    with wp.ScopedDevice(device):
        arrays, wp_radius, wp_strand, strand = _segment_arrays(assembly)
        bvh = wp.Bvh(arrays[2], arrays[3])
        todo = np.arange(m, dtype=np.int32)
        keys, segment_pairs, deepest, slots = [], 0, 0.0, 8
        while len(todo):
            # Distinct partner strands per segment, in `slots` slots; the segments with more go round again.
            n = len(todo)
            partners = wp.full((n, slots), -1, dtype=wp.int32)
            overflow, pairs = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=wp.int32)
            depth = wp.zeros(n, dtype=float)
            launch_ranges(
                _overlaps,
                n,
                [
                    bvh.id,
                    *arrays[:2],
                    wp_radius,
                    wp_strand,
                    *arrays[2:],
                    wp.array(todo, dtype=wp.int32),
                    slots,
                    partners,
                    overflow,
                    pairs,
                    depth,
                ],
                device=device,
                chunk=4096,
            )
            partners, again = partners.numpy(), overflow.numpy().astype(bool)
            done = ~again
            segment_pairs += int(pairs.numpy()[done].sum(dtype=np.int64))
            deepest = max(deepest, float(depth.numpy()[done].max(initial=0.0)))
            mine = np.repeat(strand[todo[done]], slots)
            other = partners[done].ravel()
            valid = other >= 0
            a, b = np.minimum(mine[valid], other[valid]), np.maximum(mine[valid], other[valid])
            keys.append(np.unique(a.astype(np.int64) * assembly.num_strands + b))
            todo, slots = todo[again], slots * 4
    keys = np.unique(np.concatenate(keys))
    if len(keys) == 0:
        return InterpenetrationReport(0, 0, 0, 0.0, assembly.num_strands)
    involved = np.unique(np.concatenate([keys // assembly.num_strands, keys % assembly.num_strands]))
    return InterpenetrationReport(len(keys), len(involved), segment_pairs, deepest, assembly.num_strands)


# Reports of assemblies already checked, and whether they were warned of: an assembly never changes, and a fit
# loads and prepares its scenes many times.
_checked: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def checked_interpenetration(assembly) -> InterpenetrationReport:
    """`interpenetration(assembly)`, computed once per assembly."""
    entry = _checked.get(assembly)
    if entry is None:
        entry = _checked[assembly] = [interpenetration(assembly), False]
    return entry[0]


def warn_interpenetration(assembly, rule: str = "enter") -> InterpenetrationReport:
    """Warn (InterpenetrationWarning) if strands of `assembly` interpenetrate, once per assembly; the report."""
    report = checked_interpenetration(assembly)
    entry = _checked[assembly]
    if report.pairs and not entry[1]:
        entry[1] = True
        warnings.warn(report.message(rule), InterpenetrationWarning, stacklevel=3)
    return report
