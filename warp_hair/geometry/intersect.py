"""Ray–fiber intersection: exact hits on the round tubes of a `FiberAssembly`, through an 8-wide BVH.

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
A ray that leaves a hit passes the hit's tube as `from_tube`, which is then not tested at all: it holds the
origin, so the rule above would skip it anyway.
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
The tubes' boxes go into an 8-wide BVH (`warp_hair.geometry.bvh`, which documents the layout and the build:
three levels of the binary SAH tree a node): each `BvhNode` holds the boxes of its eight children as a 6×8
matrix (one row per bound, children 0..7 in the columns) and their references, and the per-tube data sits in one
`Tube` struct array in leaf order, so that a leaf reads one contiguous block. A traversal keeps a fixed-size
local stack (`NodeStack`, a Warp vector of STACK_SIZE ints; the builder bounds the depth so that it cannot
overflow) and, at each node:

1. tests the ray against the eight child boxes at once (slab test with 1/direction computed once per ray;
   zero direction components become TINY, since 0 · inf gives NaN for a ray exactly in a box face; the near
   and far plane of each axis picked once per ray by the sign of the direction, as rows of the bound matrix;
   on the CPU as eight-lane vectors, `_CHILD_ENTRIES_SNIPPET`, reading the node where it lies), giving each
   child's entry distance, or NO_HIT where the ray misses it before the best hit so far, and a bit mask of the
   children it enters;
2. for a closest hit, descends into the one child the ray enters (most nodes), or into the nearer of two,
   pushing the other; for three or more, inserts them into the stack in order of entry and pops the nearest.

`intersect_fibers` keeps the entry distance beside each pushed child (`EntryStack`) and skips, when popping,
subtrees that the ray enters only beyond the closest hit found since: front to back, with pruning.
`fibers_occluded` returns at the first hit, which needs no order: it pushes the children the ray enters
unsorted, as Embree's shadow rays do. Which of two hits at the same t wins (only possible in the 1e-3·r seam
overlap of a joint, where both are valid and give the same t to the last bit) depends on the order of the
visit; equal entries are visited in child order.

Why 8 wide (docs/benchmarks.md, "The traversal, step by step"): a visit's slab test costs the same in eight
lanes as in four (one AVX register a row), and a ray visits a fifth to a third fewer nodes than in the 4-wide
tree of the same binary tree, with the same leaves.
"""

from __future__ import annotations

import warp as wp

from ..numerics import NO_HIT
from .bvh import LEAF_BITS, MAX_DEPTH, MAX_LEAF_SIZE

wp.set_module_options({"enable_backward": False})

# Entering roots closer than this many radii are the surface the ray starts on.
T_MIN_RADII = wp.constant(1.0e-3)
# (1 + 1e-3)²: an origin within r·(1 + 1e-3) of a tube's axis is on or inside that tube.
SURFACE_BAND2 = wp.constant(1.002001)
# Rays within 1e-6 rad of a tube's axis cannot enter its side (they would do so ~1e6·gap further on).
MIN_SIN2 = wp.constant(1.0e-12)
# Stand-in for zero direction components in the BVH slab test.
TINY = wp.constant(1.0e-30)
# Children of a BVH node: the fiber BVH is 8-wide (`build_bvh(width=BVH_WIDTH)`, three binary levels a node).
# The native snippets below (`_CHILD_ENTRIES_SNIPPET`, `_entered`) are written for eight lanes.
BVH_WIDTH = 8


def stack_slots(depth: int) -> int:
    """Traversal stack slots a tree of `depth` BVH_WIDTH-wide levels needs: a node leaves at most BVH_WIDTH − 1
    children pending, and a visit holds one more for a moment (all it enters, before the nearest is popped)."""
    return (BVH_WIDTH - 1) * depth + 1


# Slots of the traversal stack: `build_bvh` keeps the depth <= ceil(bvh.MAX_DEPTH / log2(BVH_WIDTH)) = 14.
STACK_SIZE = stack_slots(-(-MAX_DEPTH // (BVH_WIDTH.bit_length() - 1)))
NodeStack = wp.types.vector(length=STACK_SIZE, dtype=wp.int32)
EntryStack = wp.types.vector(length=STACK_SIZE, dtype=float)
# A node's children's entry distances, and their references.
Entries = wp.types.vector(length=BVH_WIDTH, dtype=float)
Children = wp.types.vector(length=BVH_WIDTH, dtype=wp.int32)
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


# A node's child boxes: rows lo_x, lo_y, lo_z, hi_x, hi_y, hi_z, each with children 0..7 in its columns, so
# that a ray picks its near and far plane of each axis by row index (`SlabRows`).
NodeBounds = wp.types.matrix(shape=(6, BVH_WIDTH), dtype=float)
# Row of the near x, y, z plane and of the far ones for a ray: the lower plane where the direction is positive.
SlabRows = wp.types.vector(length=6, dtype=wp.int32)


@wp.struct
class BvhNode:
    """A node of the 8-wide fiber BVH (`warp_hair.geometry.bvh`): the boxes of its eight children (`NodeBounds`)
    and what the children are."""

    bounds: NodeBounds
    child: Children  # >= 0: an interior node; < 0: a leaf, −1 − child = (first tube << LEAF_SHIFT) | count


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
    tube: int  # index into FiberGeometry.tubes (leaf order; −1 on a miss): rays leaving the hit skip it (`from_tube`)


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


# The slab test of `_child_entries` on the CPU as eight-lane vectors (clang's vector extension, one AVX register a
# row): Warp's element-wise code for it, with the row picked at run time, compiles to a mix of scalar and two-lane
# operations. CUDA, one ray a thread, takes the same arithmetic per lane. Both give the values the element-wise
# form gives, operation for operation: (plane − o) · inv, then max/min as `a > b ? a : b`.
_CHILD_ENTRIES_SNIPPET = """
#if defined(__CUDA_ARCH__)
    const auto& bounds = wp::address(nodes, ref)->bounds;
    wp::vec_t<8, float> out;
    for (int k = 0; k < 8; ++k) {
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
        out.c[k] = nr <= fr ? nr : no_hit;
    }
    return out;
#else
    typedef float lanes __attribute__((vector_size(32)));
    const float* b = &wp::address(nodes, ref)->bounds.data[0][0];
    lanes x0, y0, z0, x1, y1, z1;
    __builtin_memcpy(&x0, b + 8 * rows[0], 32);
    __builtin_memcpy(&y0, b + 8 * rows[1], 32);
    __builtin_memcpy(&z0, b + 8 * rows[2], 32);
    __builtin_memcpy(&x1, b + 8 * rows[3], 32);
    __builtin_memcpy(&y1, b + 8 * rows[4], 32);
    __builtin_memcpy(&z1, b + 8 * rows[5], 32);
    x0 = (x0 - origin[0]) * inv[0];
    y0 = (y0 - origin[1]) * inv[1];
    z0 = (z0 - origin[2]) * inv[2];
    x1 = (x1 - origin[0]) * inv[0];
    y1 = (y1 - origin[1]) * inv[1];
    z1 = (z1 - origin[2]) * inv[2];
    lanes zero = {0, 0, 0, 0, 0, 0, 0, 0};
    lanes hi = zero + t_hi;
    lanes miss = zero + no_hit;
    lanes a = x0 > y0 ? x0 : y0;
    lanes c = z0 > zero ? z0 : zero;
    lanes nr = a > c ? a : c;
    lanes e = x1 < y1 ? x1 : y1;
    lanes f = z1 < hi ? z1 : hi;
    lanes fr = e < f ? e : f;
    lanes out = nr <= fr ? nr : miss;
    wp::vec_t<8, float> result;
    __builtin_memcpy(&result.c[0], &out, 32);
    return result;
#endif
"""


@wp.func_native(_CHILD_ENTRIES_SNIPPET)
def _child_entries_native(
    nodes: wp.array(dtype=BvhNode), ref: int, origin: wp.vec3, inv: wp.vec3, rows: SlabRows, t_hi: float, no_hit: float
) -> Entries: ...


@wp.func
def _child_entries(g: FiberGeometry, ref: int, origin: wp.vec3, inv: wp.vec3, rows: SlabRows, t_hi: float):
    """Where the ray enters each child box of node `ref` (0 if it starts inside), NO_HIT for a miss before t_hi.
    The same values as the slab test with the min and max of each axis's two planes: (plane − o) · inv is
    monotonic in the plane for a fixed sign of inv, and never NaN (inv is finite). The node is read where it lies
    (a copy of it, which Warp's `g.nodes[ref]` makes, costs a store and a load a row)."""
    return _child_entries_native(g.nodes, ref, origin, inv, rows, t_hi, NO_HIT)


@wp.func_native("return wp::address(nodes, ref)->child.c[k];")
def _child_native(nodes: wp.array(dtype=BvhNode), ref: int, k: int) -> int: ...


@wp.func
def _child(g: FiberGeometry, ref: int, k: int):
    """Child k of node `ref`, read where it lies."""
    return _child_native(g.nodes, ref, k)


@wp.func_native(
    """
#if defined(__AVX__) && !defined(__CUDA_ARCH__)
    typedef float lanes __attribute__((vector_size(32)));
    lanes e;
    __builtin_memcpy(&e, &entry.c[0], 32);
    lanes hi = {t_hi, t_hi, t_hi, t_hi, t_hi, t_hi, t_hi, t_hi};
    return __builtin_ia32_movmskps256((lanes)(e < hi));
#else
    int mask = 0;
    for (int k = 0; k < 8; ++k)
        mask |= (entry.c[k] < t_hi ? 1 : 0) << k;
    return mask;
#endif
"""
)
def _entered(entry: Entries, t_hi: float) -> int:
    """Bit k set where the ray enters child k before t_hi."""
    ...


@wp.func_native(
    """
#if defined(__CUDA_ARCH__)
    return __ffs(mask) - 1;
#else
    return __builtin_ctz(mask);
#endif
"""
)
def _lowest_bit(mask: int) -> int:
    """The index of the lowest set bit of a nonzero mask."""
    ...


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
    hit.tube = i
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
    hit.tube = -1
    return hit


@wp.func
def intersect_fibers(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, from_tube: int):
    """The closest entering hit with t_min < t < t_max along the unit `direction`; t = NO_HIT on a miss.
    `from_tube` is the tube the ray leaves (`FiberHit.tube` of the hit it starts at; −1 for none): it is not
    tested, since the ray starts on it and a tube holding the origin has no entering hit (the module docstring);
    that saves a ray from a fiber the test of the one tube every such ray reaches, and changes no hit."""
    return _closest_hit(g, origin, direction, t_max, 0, -1, from_tube)


@wp.func
def intersect_fibers_exits(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, skip_strand: int):
    """The closest hit under the "exits" rule (Cycles 4.x on the CPU): entering or leaving any tube, except the
    tubes of strand `skip_strand` (the strand the ray leaves; −1 for none)."""
    return _closest_hit(g, origin, direction, t_max, 1, skip_strand, -1)


@wp.func
def intersect_fibers_under_rule(
    g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int, from_tube: int
):
    """The closest hit under the interpenetration rule `exits` (0: `intersect_fibers`, skipping `from_tube`; 1:
    `intersect_fibers_exits`, skipping strand `skip_strand`), in one traversal."""
    if exits != 0:
        return intersect_fibers_exits(g, origin, direction, t_max, skip_strand)
    return intersect_fibers(g, origin, direction, t_max, from_tube)


@wp.func
def fibers_occluded_under_rule(
    g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int, from_tube: int
):
    """Whether any fiber blocks the ray before t_max under the interpenetration rule `exits` (0:
    `fibers_occluded`, skipping `from_tube`; 1: `fibers_occluded_exits`, skipping strand `skip_strand`)."""
    if exits != 0:
        return fibers_occluded_exits(g, origin, direction, t_max, skip_strand)
    return fibers_occluded(g, origin, direction, t_max, from_tube)


@wp.func
def closest_tube(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, from_tube: int):
    """The preliminary closest hit (Mitsuba's `ray_intersect_preliminary`, Embree's hit): (tube, t, exit) with
    tube the index into `g.tubes` (−1 and t = NO_HIT on a miss), without the hit point or frame of
    `intersect_fibers`, which are `_make_hit(g, tube, t, origin, direction, exit)`."""
    return _closest_tube(g, origin, direction, t_max, 0, -1, from_tube)


@wp.func
def closest_tube_exits(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, skip_strand: int):
    """`closest_tube` under the "exits" rule (see `intersect_fibers_exits`)."""
    return _closest_tube(g, origin, direction, t_max, 1, skip_strand, -1)


@wp.func
def _closest_hit(
    g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int, from_tube: int
):
    best, t_best, best_exit = _closest_tube(g, origin, direction, t_max, exits, skip_strand, from_tube)
    if best < 0:
        return _no_hit()
    return _make_hit(g, best, t_best, origin, direction, best_exit)


@wp.func
def _closest_tube(
    g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int, from_tube: int
):
    if g.num_segments == 0:
        return int(-1), float(NO_HIT), int(0)
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
            entry = _child_entries(g, ref, origin, inv, rows, t_best)
            mask = _entered(entry, t_best)
            if mask != 0:
                # Most nodes have one or two children the ray enters: no sort for one, one comparison for two
                # (equal entries in child order).
                ia = _lowest_bit(mask)
                rest = mask & (mask - 1)
                if rest == 0:
                    ref = _child(g, ref, ia)
                    continue
                if (rest & (rest - 1)) == 0:
                    ib = _lowest_bit(rest)
                    ta = entry[ia]
                    tb = entry[ib]
                    near = wp.where(tb < ta, ib, ia)
                    far = ia + ib - near
                    stack[sp] = _child(g, ref, far)
                    stack_t[sp] = entry[far]
                    sp += 1
                    ref = _child(g, ref, near)
                    continue
                # Three or more: each inserted into the stack in order of entry, nearest on top (equal entries in
                # child order), and the nearest popped below.
                base = sp
                while mask != 0:
                    i = _lowest_bit(mask)
                    mask = mask & (mask - 1)
                    e = entry[i]
                    j = sp
                    while j > base:
                        if stack_t[j - 1] > e:
                            break
                        stack[j] = stack[j - 1]
                        stack_t[j] = stack_t[j - 1]
                        j -= 1
                    stack[j] = _child(g, ref, i)
                    stack_t[j] = e
                    sp += 1
        else:
            code = -1 - ref
            first = code >> LEAF_SHIFT
            for i in range(first, first + (code & LEAF_MASK)):
                if exits == 0:
                    if i != from_tube:
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
        return int(-1), float(NO_HIT), int(0)
    return best, t_best, best_exit


@wp.func
def fibers_occluded(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, from_tube: int):
    """Whether any entering hit lies in (t_min, t_max) along the unit `direction`: for shadow rays. `from_tube`
    as in `intersect_fibers`."""
    return _any_hit(g, origin, direction, t_max, 0, -1, from_tube)


@wp.func
def fibers_occluded_exits(g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, skip_strand: int):
    """Whether any hit of the "exits" rule (see `intersect_fibers_exits`) lies in (t_min, t_max)."""
    return _any_hit(g, origin, direction, t_max, 1, skip_strand, -1)


@wp.func
def _any_hit(
    g: FiberGeometry, origin: wp.vec3, direction: wp.vec3, t_max: float, exits: int, skip_strand: int, from_tube: int
):
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
            # pushed as they come, unsorted, and the first of them visited next.
            mask = _entered(_child_entries(g, ref, origin, inv, rows, t_hi), t_hi)
            if mask != 0:
                first = _lowest_bit(mask)
                mask = mask & (mask - 1)
                while mask != 0:
                    stack[sp] = _child(g, ref, _lowest_bit(mask))
                    sp += 1
                    mask = mask & (mask - 1)
                ref = _child(g, ref, first)
                continue
        else:
            code = -1 - ref
            first = code >> LEAF_SHIFT
            for i in range(first, first + (code & LEAF_MASK)):
                if exits == 0:
                    if i != from_tube and _entry_distance(g.tubes[i], origin, direction, t_hi) < t_hi:
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
