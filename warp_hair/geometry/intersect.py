"""Ray–fiber intersection: exact hits on the round tubes of a `FiberAssembly`, through a 4-wide BVH.

Geometry
--------
Every segment (p0, p1) of a strand is a round tube: the infinite cylinder of radius r = (r0 + r1) / 2 around
the segment axis, clipped by one plane at each end.

* At an interior joint the clip plane is the mitre plane, which bisects the angle between the two segments
  (normal a_k + a_{k+1}, a the unit axes). Reflection in that plane maps one cylinder onto the other, so two
  consecutive tubes of equal radius share the same ellipse in it and meet exactly: no gap, no overlap. A
  tapered strand becomes stepped (one radius per segment), with a small step at each joint.
* At the two ends of a strand the plane is perpendicular to the end segment.
* Joints bent by more than about 154° (a hairpin, where the mitre ellipse would grow without bound) and
  joints next to a zero-length segment are clipped like strand ends instead; zero-length segments are never
  hit. Segments shorter than r·tan(bend / 2) have their two clip planes cross inside the tube and become
  wedges; hair and fur polylines are far from that.

The ends are open and only entering hits count: a hit is the root of the ray–cylinder quadratic where the
ray enters the cylinder from outside, provided that point lies between the two clip planes. Exit roots are
ignored. This is what the near-field hair model needs: the fiber is a scattering surface, and a path that
scatters into the fiber (TT, TRT) continues straight through it, so a ray that starts on or inside a tube
must not see that tube again. Entering roots at t <= 1e-3·r are skipped, and so is every tube whose cylinder
holds the ray origin within r·(1 + 1e-3) of its axis (rounding can put a surface point slightly outside,
and a grazing ray from there would otherwise re-enter the same tube at a t larger than any fixed t_min).
At mitre joints each tube reaches 1e-3·r past the plane, so that float32 rounding can never open a gap in
the seam; a ray entering in that sliver hits both tubes at the same point and the closer wins.

Interpenetrating strands: the "exit" rule
-----------------------------------------
Where strands pass through each other, a ray that starts on a fiber can start inside another strand's tube;
the rule above (`intersect_fibers`, `fibers_occluded`; `[render] interpenetration = "enter"`) skips that tube,
as Mitsuba 3 does. `intersect_fibers_exits` and `fibers_occluded_exits` (`interpenetration = "exit"`) follow
Cycles 4.x on the CPU instead, whose Embree 4 round curves report exit hits too: the first root in (t_min,
t_max) of either kind counts, on every tube except those of the strand the ray leaves (Cycles skips the whole
curve a ray leaves), and a hit where the ray leaves a tube (`FiberHit.exit`) has its normal and tangent reversed,
as Cycles shades a back-facing curve hit, which makes it an entering hit of the mirrored fiber with the same h.
Both rules give the same hits wherever strands do not overlap, except that a ray never meets the strand it
leaves under "exit" (a curl's next turn, say). docs/scenes.md, "Interpenetrating strands", cites the peers'
sources and says why "enter" is the default.

The quadratic is solved relative to the segment centre in a cancellation-free form: with w = origin −
centre, b = a × d and A = |b|², the signed distance between the ray and the axis is (w·b)/√A = h·r, and the
entering root is t = −(w⊥·d + sqrt(A·r² − (w·b)²)) / A, w⊥ the part of w perpendicular to the axis.

Hit frame (docs/MODEL.md, "Frame and angles")
---------------------------------------
x = `tangent` (unit axis, root → tip), z = `normal` (outward cylinder normal, ⊥ x), y = z × x, and
h = −(wo·y) / sqrt((wo·y)² + (wo·z)²) = −cos φ_o with wo = −direction. For a ray perpendicular to the fiber,
h is the signed offset of the ray from the axis along a × d, over r.

Shading frame
-------------
A polyline's axis turns at every joint, and the BSDF frame with it: on a wave of 16 segments a period the
tangent jumps by about 10°, as wide as the R lobe, and the highlight shows steps. `shading_frame` gives the
BSDF a tangent that turns continuously along the strand instead: each vertex has a tangent (the mitre
bisector at a joint, which is the direction of a Catmull-Rom curve through equally spaced vertices; the
segment's own axis at strand ends and at joints clipped like ends), and a hit takes the normalised
interpolation of its segment's two vertex tangents by its position along the axis. The normal is the
cylinder's, made orthogonal to that tangent, and h is −cos φ_o in that frame, so that frame and offset stay
consistent as the BSDF assumes. The geometry stays the mitred tubes.

BVH traversal
-------------
The tubes' boxes go into a 4-wide BVH (`warp_hair.geometry.bvh`, which documents the layout and the build): each
`BvhNode` holds the boxes of its four children as a 6×4 matrix (one row per bound, children 0..3 in the
columns) and their references, and the per-tube data sits in one `Tube` struct array in leaf order, so that a
leaf reads one contiguous block. A traversal keeps a fixed-size local stack (`NodeStack`, a Warp vector of
STACK_SIZE ints; the builder bounds the depth so that it cannot overflow) and, at each node:

1. tests the ray against the four child boxes at once (slab test with 1/direction computed once per ray;
   zero direction components become TINY, since 0 · inf gives NaN for a ray exactly in a box face; the near
   and far plane of each axis picked once per ray by the sign of the direction, as rows of the bound matrix;
   on the CPU as four-lane vectors, `_CHILD_ENTRIES_SNIPPET`), giving each child's entry distance, or NO_HIT
   where the ray misses it before the best hit so far;
2. for a closest hit, descends into the one child the ray enters, or into the nearer of two, pushing the
   other (most nodes: 1.3–1.4 children entered on average); for three or four, sorts the (entry, child) pairs
   with a 5-comparator network, pushes the second to fourth nearest that the ray enters (farthest first,
   without branches: a miss is written and the stack pointer not advanced) and descends into the nearest.

`intersect_fibers` keeps the entry distance beside each pushed child (`EntryStack`) and skips, when popping,
subtrees that the ray enters only beyond the closest hit found since: front to back, with pruning.
`fibers_occluded` returns at the first hit, which needs no order: it pushes the children the ray enters
unsorted, as Embree's shadow rays do. Which of two hits at the same t wins (only possible in the 1e-3·r seam
overlap of a joint, where both are valid) depends on the order of the visit; the two-child path keeps the
sorting network's order (equal entries in child order).
"""

from __future__ import annotations

import warp as wp

from ..numerics import NO_HIT
from .bvh import LEAF_BITS, MAX_LEAF_SIZE

wp.set_module_options({"enable_backward": False})

# Entering roots closer than this many radii are the surface the ray starts on.
T_MIN_RADII = wp.constant(1.0e-3)
# (1 + 1e-3)²: an origin within r·(1 + 1e-3) of a tube's axis is on or inside that tube.
SURFACE_BAND2 = wp.constant(1.002001)
# Rays within 1e-6 rad of a tube's axis cannot enter its side (they would do so ~1e6·gap further on).
MIN_SIN2 = wp.constant(1.0e-12)
# Stand-in for zero direction components in the BVH slab test.
TINY = wp.constant(1.0e-30)
# Slots of the traversal stack. A 4-wide node leaves at most 3 children pending and a traversal writes up to
# 3 slots past those, so a tree of depth D needs 3·D slots; `build_bvh` keeps D <= bvh.MAX_DEPTH / 2 = 20.
STACK_SIZE = 64
NodeStack = wp.types.vector(length=STACK_SIZE, dtype=wp.int32)
EntryStack = wp.types.vector(length=STACK_SIZE, dtype=float)
# A leaf reference is −1 − ((first tube << LEAF_SHIFT) | count).
LEAF_SHIFT = wp.constant(LEAF_BITS)
LEAF_MASK = wp.constant(MAX_LEAF_SIZE)
# The traversal's "no node left".
DONE = wp.constant(2**31 - 1)


@wp.struct
class Tube:
    """One segment's tube, as the hit test reads it (all of it in one place, in BVH leaf order)."""

    center: wp.vec3  # (p0 + p1) / 2: the origin the hit test works relative to
    axis: wp.vec3  # unit (p1 − p0) / |p1 − p0|; zero for a zero-length segment
    mitre0: wp.vec3  # clip-plane normal at p0, pointing into the segment
    mitre1: wp.vec3  # clip-plane normal at p1, pointing into the segment
    clip: wp.vec2  # inside iff (x − center)·mitre0 >= clip[0] and (x − center)·mitre1 >= clip[1]
    radius: float


# A node's child boxes: rows lo_x, lo_y, lo_z, hi_x, hi_y, hi_z, each with children 0..3 in its columns, so
# that a ray picks its near and far plane of each axis by row index (`SlabRows`).
NodeBounds = wp.types.matrix(shape=(6, 4), dtype=float)
# Row of the near x, y, z plane and of the far ones for a ray: the lower plane where the direction is positive.
SlabRows = wp.types.vector(length=6, dtype=wp.int32)


@wp.struct
class BvhNode:
    """A node of the 4-wide fiber BVH (`warp_hair.geometry.bvh`): the boxes of its four children (`NodeBounds`)
    and what the children are."""

    bounds: NodeBounds
    child: wp.vec4i  # >= 0: an interior node; < 0: a leaf, −1 − child = (first tube << LEAF_SHIFT) | count


@wp.struct
class FiberGeometry:
    """What kernels need to intersect fibers; arrays live on the device of the `FiberBVH` that built it."""

    nodes: wp.array(dtype=BvhNode)  # the BVH over the tubes' boxes (the whole clipped tube, mitre overhang included)
    tubes: wp.array(dtype=Tube)  # in BVH leaf order
    segment: wp.array(dtype=wp.int32)  # index into FiberAssembly.segments() of each tube
    strand: wp.array(dtype=wp.int32)  # strand of each tube
    num_segments: int
    # Per segment (FiberAssembly.segments() order), for `shading_frame`: its start p0, its axis over its
    # length (so that (x − p0)·step runs 0 → 1 along it) and the unit tangents at its two vertices.
    start: wp.array(dtype=wp.vec3)
    step: wp.array(dtype=wp.vec3)
    tangent0: wp.array(dtype=wp.vec3)
    tangent1: wp.array(dtype=wp.vec3)


@wp.struct
class FiberHit:
    t: float  # distance along the unit ray; NO_HIT (1e30) when nothing was hit
    segment: int  # index into FiberAssembly.segments(); −1 on a miss
    strand: int  # −1 on a miss
    position: wp.vec3  # on the cylinder surface
    tangent: wp.vec3  # unit segment axis, root → tip: the BSDF's x
    normal: wp.vec3  # unit outward normal at the hit, ⊥ tangent: the BSDF's z
    h: float  # −(wo·y) / sqrt((wo·y)² + (wo·z)²) in [−1, 1], wo = −direction, y = normal × tangent
    exit: int  # 1 where the ray leaves the tube (the "exits" rule only): normal and tangent are then reversed


@wp.func
def _entry_distance(tube: Tube, origin: wp.vec3, direction: wp.vec3, t_hi: float):
    """t of the ray's entering hit on the tube if it lies in (t_min, t_hi), else NO_HIT."""
    a = tube.axis
    b = wp.cross(a, direction)
    aa = wp.dot(b, b)
    r = tube.radius
    w = origin - tube.center
    hr = wp.abs(wp.dot(w, b))
    gr = r * wp.sqrt(aa)
    # The ray line passes the axis farther than r (this also rejects rays parallel to the axis).
    if hr >= gr or aa <= MIN_SIN2:
        return NO_HIT
    w_perp = w - wp.dot(w, a) * a
    if wp.dot(w_perp, w_perp) <= r * r * SURFACE_BAND2:
        return NO_HIT
    t = -(wp.dot(w_perp, direction) + wp.sqrt((gr - hr) * (gr + hr))) / aa
    if t <= T_MIN_RADII * r or t >= t_hi:
        return NO_HIT
    p = w + t * direction
    clip = tube.clip
    if wp.dot(p, tube.mitre0) < clip[0] or wp.dot(p, tube.mitre1) < clip[1]:
        return NO_HIT
    return t


@wp.func
def _inside_clip(tube: Tube, p: wp.vec3):
    """Whether p (relative to the tube's centre) lies between the tube's two clip planes."""
    clip = tube.clip
    return wp.dot(p, tube.mitre0) >= clip[0] and wp.dot(p, tube.mitre1) >= clip[1]


@wp.func
def _crossing_distance(tube: Tube, origin: wp.vec3, direction: wp.vec3, t_hi: float):
    """(t, exit) of the ray's first crossing of the tube's side in (t_min, t_hi), entering (exit = 0) or leaving
    it (exit = 1); (NO_HIT, 0) if none. The "exits" rule: no origin is skipped, so a ray that starts inside the
    tube sees where it leaves."""
    a = tube.axis
    b = wp.cross(a, direction)
    aa = wp.dot(b, b)
    r = tube.radius
    w = origin - tube.center
    hr = wp.abs(wp.dot(w, b))
    gr = r * wp.sqrt(aa)
    if hr >= gr or aa <= MIN_SIN2:
        return NO_HIT, 0
    w_perp = w - wp.dot(w, a) * a
    half = wp.sqrt((gr - hr) * (gr + hr))
    t_min = T_MIN_RADII * r
    t = -(wp.dot(w_perp, direction) + half) / aa
    if t > t_min and t < t_hi and _inside_clip(tube, w + t * direction):
        return t, 0
    t = -(wp.dot(w_perp, direction) - half) / aa
    if t > t_min and t < t_hi and _inside_clip(tube, w + t * direction):
        return t, 1
    return NO_HIT, 0


@wp.func
def _inverse_direction(d: wp.vec3):
    """1 / d for the slab test, with zero components replaced by TINY (0 · inf would give NaN)."""
    return wp.vec3(
        1.0 / wp.where(d[0] == 0.0, TINY, d[0]),
        1.0 / wp.where(d[1] == 0.0, TINY, d[1]),
        1.0 / wp.where(d[2] == 0.0, TINY, d[2]),
    )


@wp.func
def _slab_rows(inv: wp.vec3):
    """The `NodeBounds` rows of the planes where the ray enters (near x, y, z) and leaves (far x, y, z) each slab:
    chosen once per ray, so that the box test needs no per-axis min and max of the two planes."""
    nx = wp.where(inv[0] < 0.0, 3, 0)
    ny = wp.where(inv[1] < 0.0, 4, 1)
    nz = wp.where(inv[2] < 0.0, 5, 2)
    return SlabRows(wp.int32(nx), wp.int32(ny), wp.int32(nz), wp.int32(3 - nx), wp.int32(5 - ny), wp.int32(7 - nz))


# The slab test of `_child_entries` on the CPU as four-lane vectors (clang's vector extension, one SSE register a
# row): Warp's element-wise vec4 code for it, with the row picked at run time, compiles to a mix of scalar and
# two-lane operations. CUDA, one ray a thread, takes the same arithmetic per lane. Both give the values the
# element-wise form gives, operation for operation: (plane − o) · inv, then max/min as `a > b ? a : b`.
_CHILD_ENTRIES_SNIPPET = """
#if defined(__CUDA_ARCH__)
    float out[4];
    for (int k = 0; k < 4; ++k) {
        float x0 = (bounds.data[rows[0]][k] - origin[0]) * inv[0];
        float y0 = (bounds.data[rows[1]][k] - origin[1]) * inv[1];
        float z0 = (bounds.data[rows[2]][k] - origin[2]) * inv[2];
        float x1 = (bounds.data[rows[3]][k] - origin[0]) * inv[0];
        float y1 = (bounds.data[rows[4]][k] - origin[1]) * inv[1];
        float z1 = (bounds.data[rows[5]][k] - origin[2]) * inv[2];
        float a = x0 > y0 ? x0 : y0;
        float c = z0 > 0.0f ? z0 : 0.0f;
        float nr = a > c ? a : c;
        float e = x1 < y1 ? x1 : y1;
        float f = z1 < t_hi ? z1 : t_hi;
        float fr = e < f ? e : f;
        out[k] = nr <= fr ? nr : no_hit;
    }
    return wp::vec4(out[0], out[1], out[2], out[3]);
#else
    typedef float lanes __attribute__((vector_size(16)));
    const float* b = &bounds.data[0][0];
    lanes x0, y0, z0, x1, y1, z1;
    __builtin_memcpy(&x0, b + 4 * rows[0], 16);
    __builtin_memcpy(&y0, b + 4 * rows[1], 16);
    __builtin_memcpy(&z0, b + 4 * rows[2], 16);
    __builtin_memcpy(&x1, b + 4 * rows[3], 16);
    __builtin_memcpy(&y1, b + 4 * rows[4], 16);
    __builtin_memcpy(&z1, b + 4 * rows[5], 16);
    x0 = (x0 - origin[0]) * inv[0];
    y0 = (y0 - origin[1]) * inv[1];
    z0 = (z0 - origin[2]) * inv[2];
    x1 = (x1 - origin[0]) * inv[0];
    y1 = (y1 - origin[1]) * inv[1];
    z1 = (z1 - origin[2]) * inv[2];
    lanes zero = {0.0f, 0.0f, 0.0f, 0.0f};
    lanes hi = {t_hi, t_hi, t_hi, t_hi};
    lanes miss = {no_hit, no_hit, no_hit, no_hit};
    lanes a = x0 > y0 ? x0 : y0;
    lanes c = z0 > zero ? z0 : zero;
    lanes nr = a > c ? a : c;
    lanes e = x1 < y1 ? x1 : y1;
    lanes f = z1 < hi ? z1 : hi;
    lanes fr = e < f ? e : f;
    lanes out = nr <= fr ? nr : miss;
    return wp::vec4(out[0], out[1], out[2], out[3]);
#endif
"""


@wp.func_native(_CHILD_ENTRIES_SNIPPET)
def _child_entries_native(
    bounds: NodeBounds, origin: wp.vec3, inv: wp.vec3, rows: SlabRows, t_hi: float, no_hit: float
) -> wp.vec4: ...


@wp.func
def _child_entries(node: BvhNode, origin: wp.vec3, inv: wp.vec3, rows: SlabRows, t_hi: float):
    """Where the ray enters each child box of the node (0 if it starts inside), NO_HIT for a miss before t_hi.
    The same values as the slab test with the min and max of each axis's two planes: (plane − o) · inv is
    monotonic in the plane for a fixed sign of inv, and never NaN (inv is finite)."""
    return _child_entries_native(node.bounds, origin, inv, rows, t_hi, NO_HIT)


@wp.func
def _compare_swap(ta: float, tb: float, a: int, b: int):
    """The two (entry, child) pairs in order of entry."""
    swap = tb < ta
    return wp.where(swap, tb, ta), wp.where(swap, ta, tb), wp.where(swap, b, a), wp.where(swap, a, b)


@wp.func
def _sort_entries(entry: wp.vec4, child: wp.vec4i):
    """The node's four children and their entry distances, nearest first (misses, at NO_HIT, last):
    a five-comparator sorting network, no branches."""
    t0, t1, c0, c1 = _compare_swap(entry[0], entry[1], child[0], child[1])
    t2, t3, c2, c3 = _compare_swap(entry[2], entry[3], child[2], child[3])
    t0, t2, c0, c2 = _compare_swap(t0, t2, c0, c2)
    t1, t3, c1, c3 = _compare_swap(t1, t3, c1, c3)
    t1, t2, c1, c2 = _compare_swap(t1, t2, c1, c2)
    return t0, t1, t2, t3, c0, c1, c2, c3


@wp.func
def _make_hit(g: FiberGeometry, i: int, t: float, origin: wp.vec3, direction: wp.vec3, exit: int):
    tube = g.tubes[i]
    a = tube.axis
    r = tube.radius
    w = origin - tube.center
    along = wp.dot(w, a) + t * wp.dot(direction, a)
    # The radial part of the hit, rebuilt from the exact 2D geometry so that the position lies on the surface
    # (|distance to the axis| = r) even when t carries the rounding of a distant origin.
    b = wp.cross(a, direction)
    inv_len = 1.0 / wp.length(b)
    offset = wp.clamp(wp.dot(w, b) * inv_len / r, -1.0, 1.0)
    across = (direction - wp.dot(direction, a) * a) * inv_len
    z = wp.normalize(offset * b * inv_len - wp.sqrt((1.0 - offset) * (1.0 + offset)) * across)
    position = tube.center + along * a + r * z
    if exit != 0:
        # Leaving the tube: the outward normal there faces along the ray. As Cycles shades a back-facing curve
        # hit, normal and tangent are reversed, which makes it an entering hit of the mirrored fiber (same h).
        out = wp.normalize(offset * b * inv_len + wp.sqrt((1.0 - offset) * (1.0 + offset)) * across)
        position = tube.center + along * a + r * out
        z = -out
        a = -a
    y = wp.cross(z, a)
    wo_y = -wp.dot(direction, y)
    wo_z = -wp.dot(direction, z)

    hit = FiberHit()
    hit.t = t
    hit.segment = int(g.segment[i])
    hit.strand = int(g.strand[i])
    hit.position = position
    hit.tangent = a
    hit.normal = z
    hit.h = wp.clamp(-wo_y / wp.sqrt(wo_y * wo_y + wo_z * wo_z), -1.0, 1.0)
    hit.exit = exit
    return hit


@wp.func
def shading_frame(g: FiberGeometry, hit: FiberHit, direction: wp.vec3):
    """(x, z, h) for the BSDF at a fiber hit: the tangent interpolated between the segment's vertex tangents,
    the cylinder normal made orthogonal to it, and h = −cos φ_o in that frame (see the module docstring)."""
    i = hit.segment
    s = wp.clamp(wp.dot(hit.position - g.start[i], g.step[i]), 0.0, 1.0)
    x = wp.normalize((1.0 - s) * g.tangent0[i] + s * g.tangent1[i])
    if hit.exit != 0:
        x = -x
    z = wp.normalize(hit.normal - wp.dot(hit.normal, x) * x)
    y = wp.cross(z, x)
    wo_y = -wp.dot(direction, y)
    wo_z = -wp.dot(direction, z)
    den = wo_y * wo_y + wo_z * wo_z
    h = hit.h
    if den > 0.0:  # 0 only for a ray along the shading tangent, which the geometric h still describes
        h = wp.clamp(-wo_y / wp.sqrt(den), -1.0, 1.0)
    return x, z, h


@wp.func
def _no_hit():
    hit = FiberHit()
    hit.t = NO_HIT
    hit.segment = -1
    hit.strand = -1
    hit.exit = 0
    return hit


@wp.func
def intersect_fibers(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float):
    """The closest entering hit with t_min < t < t_max along the unit `direction`; t = NO_HIT on a miss."""
    return _closest_hit(g, origin, direction, t_max, 0, -1)


@wp.func
def intersect_fibers_exits(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, skip_strand: int):
    """The closest hit under the "exits" rule (Cycles 4.x on the CPU): entering or leaving any tube, except the
    tubes of strand `skip_strand` (the strand the ray leaves; −1 for none)."""
    return _closest_hit(g, origin, direction, t_max, 1, skip_strand)


@wp.func
def _closest_hit(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int):
    if g.num_segments == 0:
        return _no_hit()
    inv = _inverse_direction(direction)
    rows = _slab_rows(inv)
    t_best = wp.min(t_max, NO_HIT)
    best = int(-1)
    best_exit = int(0)
    stack = NodeStack()
    stack_t = EntryStack()
    sp = int(0)
    ref = int(0)
    while ref != DONE:
        if ref >= 0:
            node = g.nodes[ref]
            entry = _child_entries(node, origin, inv, rows, t_best)
            h0 = entry[0] < t_best
            h1 = entry[1] < t_best
            h2 = entry[2] < t_best
            h3 = entry[3] < t_best
            hits = wp.where(h0, 1, 0) + wp.where(h1, 1, 0) + wp.where(h2, 1, 0) + wp.where(h3, 1, 0)
            # Most nodes have one or two children the ray enters: no sort for one, one comparison for two (the
            # order the sorting network gives, which keeps two equal entries in child order).
            if hits == 1:
                ref = wp.where(
                    h0, node.child[0], wp.where(h1, node.child[1], wp.where(h2, node.child[2], node.child[3]))
                )
                continue
            if hits == 2:
                ia = wp.where(h0, 0, wp.where(h1, 1, 2))
                ib = wp.where(h3, 3, wp.where(h2, 2, 1))
                ta = entry[ia]
                tb = entry[ib]
                near = wp.where(tb < ta, ib, ia)
                far = ia + ib - near
                stack[sp] = wp.int32(node.child[far])
                stack_t[sp] = entry[far]
                sp += 1
                ref = node.child[near]
                continue
            t0, t1, t2, t3, c0, c1, c2, c3 = _sort_entries(entry, node.child)
            # Push the children the ray enters after the nearest, farthest first (a miss is written and left) ...
            stack[sp] = wp.int32(c3)
            stack_t[sp] = t3
            sp += wp.where(t3 < t_best, 1, 0)
            stack[sp] = wp.int32(c2)
            stack_t[sp] = t2
            sp += wp.where(t2 < t_best, 1, 0)
            stack[sp] = wp.int32(c1)
            stack_t[sp] = t1
            sp += wp.where(t1 < t_best, 1, 0)
            # ... and visit the nearest next.
            if t0 < t_best:
                ref = c0
                continue
        else:
            code = -1 - ref
            first = code >> LEAF_SHIFT
            for i in range(first, first + (code & LEAF_MASK)):
                if exits == 0:
                    t = _entry_distance(g.tubes[i], origin, direction, t_best)
                    if t < t_best:
                        t_best = t
                        best = i
                elif g.strand[i] != skip_strand:
                    t, leaving = _crossing_distance(g.tubes[i], origin, direction, t_best)
                    if t < t_best:
                        t_best = t
                        best = i
                        best_exit = leaving
        # Pop the nearest pending subtree that the ray enters before the best hit so far.
        ref = DONE
        while sp > 0:
            sp -= 1
            if stack_t[sp] < t_best:
                ref = int(stack[sp])
                break
    if best < 0:
        return _no_hit()
    return _make_hit(g, best, t_best, origin, direction, best_exit)


@wp.func
def fibers_occluded(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float):
    """Whether any entering hit lies in (t_min, t_max) along the unit `direction`: for shadow rays."""
    return _any_hit(g, origin, direction, t_max, 0, -1)


@wp.func
def fibers_occluded_exits(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, skip_strand: int):
    """Whether any hit of the "exits" rule (see `intersect_fibers_exits`) lies in (t_min, t_max)."""
    return _any_hit(g, origin, direction, t_max, 1, skip_strand)


@wp.func
def _any_hit(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int):
    if g.num_segments == 0:
        return False
    inv = _inverse_direction(direction)
    rows = _slab_rows(inv)
    t_hi = wp.min(t_max, NO_HIT)
    stack = NodeStack()
    sp = int(0)
    ref = int(0)
    while ref != DONE:
        if ref >= 0:
            # Any hit ends the search, so the order of the visit does not matter: the children the ray enters are
            # pushed as they come, unsorted, and the last of them popped next.
            node = g.nodes[ref]
            entry = _child_entries(node, origin, inv, rows, t_hi)
            stack[sp] = wp.int32(node.child[3])
            sp += wp.where(entry[3] < t_hi, 1, 0)
            stack[sp] = wp.int32(node.child[2])
            sp += wp.where(entry[2] < t_hi, 1, 0)
            stack[sp] = wp.int32(node.child[1])
            sp += wp.where(entry[1] < t_hi, 1, 0)
            if entry[0] < t_hi:
                ref = node.child[0]
                continue
        else:
            code = -1 - ref
            first = code >> LEAF_SHIFT
            for i in range(first, first + (code & LEAF_MASK)):
                if exits == 0:
                    if _entry_distance(g.tubes[i], origin, direction, t_hi) < t_hi:
                        return True
                elif g.strand[i] != skip_strand:
                    t, _leaving = _crossing_distance(g.tubes[i], origin, direction, t_hi)
                    if t < t_hi:
                        return True
        ref = DONE
        if sp > 0:
            sp -= 1
            ref = int(stack[sp])
    return False
