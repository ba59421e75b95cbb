"""`FiberBVH`: a `FiberAssembly` turned into the tubes the device ray test reads (mitred joints, open clipped ends,
vertex tangents for the shading frame) and their 8-wide BVH, kept alive on one device. intersect.py's
docstring explains the tube geometry."""

from __future__ import annotations

import numpy as np
import warp as wp

from .bvh import TRAVERSAL_COST, build_bvh
from .intersect import BVH_WIDTH, STACK_SIZE, BvhNode, FiberGeometry, Tube, stack_slots

# Tubes per BVH leaf, at most (the cost of a node visit relative to a tube test is bvh.TRAVERSAL_COST): in the
# 8-wide tree no other size measured takes fewer instructions a ray on both benchmark swatches
# (docs/benchmarks.md, "The traversal, step by step": leaves of 1 at node cost 0.5 and 1, of 3 and 4 at 1), and
# leaves of 4 or 7 render a swatch a few percent slower.
MAX_LEAF = 2
# Mitre joints overlap by this many radii past the mitre plane (see the module docstring).
JOINT_OVERLAP = 1.0e-3
# Joints bent further than this (cos of the angle between the segments) are clipped like strand ends.
MIN_JOINT_COS = -0.9
# Segments shorter than this many radii are treated as zero-length.
MIN_LENGTH_RADII = 1.0e-6


class FiberBVH:
    """The tube data and 8-wide BVH of a `FiberAssembly` on a device; keeps them alive.

    `geometry` is the `FiberGeometry` that kernels take; `bounds` is (lo (3,), hi (3,)) float64, the box
    around every tube. Segment indices are those of `assembly.segments()`. `smooth_tangents=False` gives
    `shading_frame` each segment's own axis: the polyline's frame, with its jumps at the joints.

    The tree is built on the host whatever `device` is, and the finished arrays are uploaded to `device` once per
    scene (a fit prepares its scenes once, so that is once per fit). The build's kernels do run on a GPU
    (`build_bvh(device=...)`), but there they are slower: one thread a range serialises the top levels, and on an
    H200 a 10⁶-segment build took 6.5 s against 2.0 s on the host's 16 cores (`benchmarks/gpu.py`, 2026-12-04);
    its trees also differ from the host's where the GPU's fused multiply-adds round an SAH cost otherwise, which
    would make a GPU render's ties differ from the CPU's. Warp's own builder (`wp.Bvh`) gives a binary tree in its
    own layout, not the 8-wide nodes over leaf-ordered tubes that intersect.py reads. The host build costs about
    3 CPU µs per segment (docs/scaling.md): nothing beside a fit's hundreds of renders.
    """

    def __init__(self, assembly, device="cpu", smooth_tangents=True):
        self.device = device
        p0, p1, r0, r1, strand, _ = assembly.segments()
        seg = segment_frames(p0, p1, r0, r1, strand)
        lowers, uppers = segment_boxes(seg)
        if len(lowers):
            self.bounds = (lowers.min(axis=0), uppers.max(axis=0))
        else:
            self.bounds = (np.zeros(3), np.zeros(3))
        reference, lowers, uppers = segment_pieces(seg, lowers, uppers)

        tree = build_bvh(lowers, uppers, max_leaf=MAX_LEAF, width=BVH_WIDTH, traversal_cost=TRAVERSAL_COST)
        if stack_slots(tree.depth) > STACK_SIZE:
            raise ValueError(f"BVH depth {tree.depth} is too deep for the traversal stack ({STACK_SIZE})")
        order = reference[tree.order]
        nodes = np.zeros(len(tree.child), dtype=BvhNode.numpy_dtype())
        # Rows lo_x, lo_y, lo_z, hi_x, hi_y, hi_z (intersect.NodeBounds), children in the columns.
        nodes["bounds"] = np.concatenate([tree.lo, tree.hi], axis=2).transpose(0, 2, 1)
        nodes["child"] = tree.child
        tubes = np.zeros(len(order), dtype=Tube.numpy_dtype())
        for name in ("center", "axis", "mitre0", "mitre1", "clip", "radius"):
            tubes[name] = seg[name][order]

        g = FiberGeometry()
        g.nodes = wp.array(nodes, dtype=BvhNode, device=device)
        g.tubes = wp.array(tubes, dtype=Tube, device=device)
        g.segment = wp.array(order.astype(np.int32), dtype=wp.int32, device=device)
        g.strand = wp.array(np.asarray(strand, dtype=np.int32)[order], dtype=wp.int32, device=device)
        g.num_segments = len(p0)
        length = np.linalg.norm(seg["p1"] - seg["p0"], axis=1)
        step = seg["axis"] / np.where(length > 0.0, length, 1.0)[:, None]
        tangent0, tangent1 = seg["tangent0"], seg["tangent1"]
        if not smooth_tangents:
            tangent0, tangent1 = seg["axis"], seg["axis"]
        for name, values in (("start", seg["p0"]), ("step", step), ("tangent0", tangent0), ("tangent1", tangent1)):
            setattr(g, name, wp.array(values.astype(np.float32), dtype=wp.vec3, device=device))
        self._geometry = g

    @property
    def geometry(self) -> FiberGeometry:
        return self._geometry

    @property
    def num_segments(self) -> int:
        return self._geometry.num_segments


def segment_frames(p0, p1, r0, r1, strand):
    """Per-segment centre, unit axis, radius, clip-plane normals and offsets, in float64."""
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    radius = (np.asarray(r0, dtype=np.float64) + np.asarray(r1, dtype=np.float64)) / 2
    center = (p0 + p1) / 2
    length = np.linalg.norm(p1 - p0, axis=1)
    solid = length > MIN_LENGTH_RADII * radius
    axis = np.zeros_like(p0)
    axis[solid] = (p1 - p0)[solid] / length[solid, None]

    mitre0, mitre1 = axis.copy(), -axis
    overlap0, overlap1 = np.zeros_like(radius), np.zeros_like(radius)
    # Joint k sits between segments k and k + 1 of the same strand.
    joint = np.flatnonzero(
        (strand[1:] == strand[:-1])
        & solid[1:]
        & solid[:-1]
        & (np.einsum("ij,ij->i", axis[1:], axis[:-1]) > MIN_JOINT_COS)
    )
    bisector = axis[joint] + axis[joint + 1]
    bisector /= np.linalg.norm(bisector, axis=1, keepdims=True)
    mitre1[joint] = -bisector
    mitre0[joint + 1] = bisector
    overlap1[joint] = JOINT_OVERLAP * radius[joint]
    overlap0[joint + 1] = JOINT_OVERLAP * radius[joint + 1]
    # Vertex tangents for the shading frame: the bisector at a mitred joint, the segment's axis elsewhere.
    tangent0, tangent1 = axis.copy(), axis.copy()
    tangent1[joint] = bisector
    tangent0[joint + 1] = bisector

    clip = np.stack(
        [
            np.einsum("ij,ij->i", p0 - center, mitre0) - overlap0,
            np.einsum("ij,ij->i", p1 - center, mitre1) - overlap1,
        ],
        axis=1,
    )
    return {
        "p0": p0,
        "p1": p1,
        "center": center,
        "axis": axis,
        "radius": radius,
        "mitre0": mitre0,
        "mitre1": mitre1,
        "clip": clip,
        "tangent0": tangent0,
        "tangent1": tangent1,
    }


def segment_boxes(seg):
    """Boxes around each clipped tube: the union of the boxes of its two end ellipses, padded for rounding."""
    axis, radius = seg["axis"], seg["radius"]
    # Rows k of the projector I − a aᵀ: the unit axis e_k with its component along the tube axis removed.
    projector = np.eye(3)[None] - axis[:, :, None] * axis[:, None, :]
    lowers, uppers = [], []
    for end, mitre in ((seg["p0"], seg["mitre0"]), (seg["p1"], seg["mitre1"])):
        cos = np.einsum("ij,ij->i", axis, mitre)
        cos = np.where(cos != 0, cos, 1.0)  # zero-length segments (zero axis and normals): a point
        mitre_perp = mitre - cos[:, None] * axis
        # The ellipse is end + r·(u − (u·m)/(a·m)·a) over unit u ⊥ a: its extent along e_k is
        # r·|e_k⊥ − (a_k / (a·m))·m⊥|.
        spread = projector - (axis / cos[:, None])[:, :, None] * mitre_perp[:, None, :]
        half = radius[:, None] * np.linalg.norm(spread, axis=2)
        lowers.append(end - half)
        uppers.append(end + half)
    return _padded(np.minimum(*lowers), np.maximum(*uppers), radius[:, None])


def _padded(lo, hi, radius):
    """A box grown for what it must also hold: the joint overlap reaches a few 1e-3·r past the mitre plane, and
    float32 rounding of the corners is relative."""
    pad = 0.01 * radius + 1e-6 * np.maximum(np.abs(lo), np.abs(hi))
    return lo - pad, hi + pad


# A segment that runs across the coordinate axes has a box far larger than its tube: a long slanted segment of
# a thin strand, as in a groom of few segments a strand. The BVH then holds it as pieces (Martinek et al., VMV
# 2018, subdivide such fibers; Embree splits curve references spatially): references to the same tube, each with
# the box of one stretch of it. A segment is cut into one piece per SPLIT_RADII radii it runs across its main
# axis, at most MAX_PIECES: on the 10⁵-strand groom of 10 segments a strand in benchmarks/scaling.py that is 3.0
# references a segment, the SAH cost 7263 → 2116 and the render 4.8× faster; 8 radii and 4 pieces, or 4 and 8,
# cost 3.8 and 7.6 references for little more (docs/benchmarks.md, "Long segments"). Swatches of short or
# axis-aligned segments are not cut.
SPLIT_RADII = 16.0
MAX_PIECES = 4


def segment_pieces(seg, lowers, uppers):
    """(segment of each BVH reference, the references' boxes): segments that run far across the axes cut into
    pieces; the others one reference with their own box (`lowers`, `uppers`: `segment_boxes`).

    A piece between two cuts is the convex hull of the tube's cross-sections there, so its box is the union of
    theirs: discs ⊥ the axis inside the segment, the mitre ellipse at either end. That holds only where a cut
    lies beyond the end's ellipse, which reaches r·tan φ along the axis either side of the end (φ between mitre
    normal and axis): segments too short for that are cut into fewer pieces."""
    axis, radius = seg["axis"], seg["radius"]
    n = len(radius)
    length = np.linalg.norm(seg["p1"] - seg["p0"], axis=1)
    across = length * np.sqrt(np.maximum(0.0, 1.0 - np.max(axis**2, axis=1)))
    pieces = np.clip(np.floor(across / (SPLIT_RADII * radius)), 1, MAX_PIECES).astype(np.int64)
    reach = np.zeros(n)
    for mitre in (seg["mitre0"], seg["mitre1"]):
        cos = np.abs(np.einsum("ij,ij->i", axis, mitre))
        reach = np.maximum(reach, radius * np.sqrt(np.maximum(0.0, 1.0 - cos**2)) / np.maximum(cos, 1e-6))
    fits = np.floor(length / (1.01 * reach + 1e-3 * radius + 1e-30)).astype(np.int64)
    pieces = np.maximum(1, np.minimum(pieces, fits))
    reference = np.repeat(np.arange(n), pieces)
    if np.all(pieces == 1):
        return reference, lowers, uppers
    lo, hi = lowers[reference], uppers[reference]
    # Only the cut segments' pieces get boxes of their own (the arrays below are as long as those alone).
    rows = np.flatnonzero(pieces[reference] > 1)
    which = reference[rows]
    k = pieces[which]
    j = rows - (np.cumsum(pieces) - pieces)[which]
    p0, d = seg["p0"][which], (seg["p1"] - seg["p0"])[which]
    cut0, cut1 = p0 + d * (j / k)[:, None], p0 + d * ((j + 1) / k)[:, None]
    r = radius[which, None]
    disc = r * np.sqrt(np.maximum(0.0, 1.0 - axis[which] ** 2))  # a disc's extent along e_k: r·|e_k − a_k a|
    piece_lo, piece_hi = _padded(np.minimum(cut0, cut1) - disc, np.maximum(cut0, cut1) + disc, r)
    for end, at_end in (("0", j == 0), ("1", j == k - 1)):
        ends = which[at_end]
        ellipse = {name: seg[name][ends] for name in ("axis", "radius")}
        ellipse["p0"] = ellipse["p1"] = seg["p" + end][ends]
        ellipse["mitre0"] = ellipse["mitre1"] = seg["mitre" + end][ends]
        end_lo, end_hi = segment_boxes(ellipse)
        piece_lo[at_end] = np.minimum(piece_lo[at_end], end_lo)
        piece_hi[at_end] = np.maximum(piece_hi[at_end], end_hi)
    # Never beyond the whole segment's box.
    lo[rows] = np.maximum(piece_lo, lo[rows])
    hi[rows] = np.minimum(piece_hi, hi[rows])
    return reference, lo, hi
