"""A bounding volume hierarchy over axis-aligned boxes, built and traversed in Warp kernels.

Layout
------
`build_bvh` returns a `Tree` of flat arrays, ready to become Warp arrays; `width` is 2 (binary), 4 or 8:

* `order` (M,): the primitives in leaf order. Every leaf covers a contiguous range of it, so the caller
  stores its per-primitive data in this order and a leaf reads one contiguous block.
* `lo`, `hi` (N, width, 3) float32: node k holds the boxes of its children, not its own, so that one node
  fetch tests all its children and the traversal can visit the nearest first.
* `child` (N, width) int32: a child >= 0 is an interior node; a child < 0 is a leaf, `leaf_range(child)` =
  (start, count) into `order`, count <= `MAX_LEAF_SIZE`.

Node 0 is the root. Unused child slots (a wide node may have fewer children than slots, a one-primitive tree has
one) are empty leaves (count 0) in a box at 1e30 in every coordinate: no ray of unit direction gets there
before t ≈ 1e30, and one that does finds nothing. An empty set has no nodes at all and must not be traversed.

Construction
------------
The binary tree is built top down, one level at a time: a Warp kernel with one thread per node of the level
bins the node's primitives by box centre along each axis (`BINS` bins over the centres' extent, all three axes
in one pass), and the node is split at the bin boundary of least surface area heuristic (SAH) cost, the area of
each side's box times its number of primitives; a second kernel partitions each node's range stably. The
primitives' boxes move with their indices, so every pass reads contiguous memory. The levels' bookkeeping (which
ranges become leaves, node ids) is NumPy over the nodes, not the primitives. A node becomes a leaf when it
holds at most `max_leaf` primitives and the heuristic prefers that to splitting. Nodes whose centres all fall
in one bin, and all nodes once the tree is deep enough that SAH splits could exceed `MAX_DEPTH`, are split at
the median instead (sorted in NumPy: rare), so the depth never exceeds MAX_DEPTH interior nodes. The build is
in float64 and deterministic: tests/helpers/reference_bvh.py, the same algorithm in NumPy, gives the same tree.
Build time and memory per segment, 10³ to 10⁶ segments: `benchmarks/scaling.py`.

A wider tree collapses the binary one: the 4-wide tree's nodes are the binary nodes at even depth, and their
children are their binary grandchildren (or a child itself, where that is a leaf); the 8-wide tree's are the
binary nodes at depths 0, 3, 6, …, with the descendants three levels down as children.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import warp as wp

from ..parallel import launch_ranges

wp.set_module_options({"enable_backward": False, "optimization_level": 3})

# Bits of a leaf code that hold the primitive count.
LEAF_BITS = 3
MAX_LEAF_SIZE = (1 << LEAF_BITS) - 1
BINS = 16
# Most interior nodes on any root-to-leaf path of the binary tree (ceil(MAX_DEPTH / 3) in the 8-wide one), which
# bounds what a traversal stack must hold.
MAX_DEPTH = 40
# Cost of testing a node's child boxes, relative to one primitive test: an 8-wide visit takes about half a tube
# test's instructions, and of 0.25, 0.35, 0.5, 1 and 2 the value 0.5 gives the fewest instructions a ray on both
# benchmark swatches (docs/benchmarks.md, "The traversal, step by step").
TRAVERSAL_COST = 0.5
# Levels with fewer ranges than this are split in one launch, not over the thread pool.
PARALLEL_RANGES = 256
# Corner of the box of an empty child slot.
EMPTY_BOX = 1.0e30


class Tree(NamedTuple):
    order: np.ndarray  # (M,) int64: the primitives in leaf order
    lo: np.ndarray  # (N, width, 3) float32: lower corners of each node's child boxes
    hi: np.ndarray  # (N, width, 3) float32: upper corners
    child: np.ndarray  # (N, width) int32: interior node index (>= 0) or leaf code (< 0) of each child
    depth: int  # interior nodes on the longest root-to-leaf path
    level: np.ndarray  # (N,) int64: depth of each node, 0 at the root

    @property
    def width(self) -> int:
        return self.child.shape[1]


def leaf_code(start, count):
    return -1 - ((np.asarray(start, dtype=np.int64) << LEAF_BITS) | count)


def leaf_range(code):
    """(start, count) of a leaf child code."""
    code = -1 - np.asarray(code, dtype=np.int64)
    return code >> LEAF_BITS, code & MAX_LEAF_SIZE


def build_bvh(
    lowers,
    uppers,
    max_leaf: int = 4,
    width: int = 2,
    traversal_cost: float = TRAVERSAL_COST,
    threads: int | None = None,
    device: str = "cpu",
) -> Tree:
    """The tree of the given `width` (2, 4 or 8) over the boxes (lowers, uppers) (M, 3); see the module docstring.
    The passes over the primitives run on `device`; on the CPU a level's ranges are split by `threads` threads
    (default: one per core). The tree does not depend on their number, but a GPU's may differ from the CPU's in
    near-ties of the SAH cost (fused multiply-adds), and there the top levels run one thread a range: `FiberBVH`
    builds on the host (tubes.py says why)."""
    if width not in (2, 4, 8):
        raise ValueError(f"width must be 2, 4 or 8, got {width}")
    tree = build_binary(lowers, uppers, max_leaf, traversal_cost, threads, device)
    return tree if width == 2 else _widen(tree, width)


def half_area(box):
    """Half the surface area of boxes stored as (lo, −hi) along the first axis (6, ...); 0 for empty ones."""
    d = np.maximum(-box[3:] - box[:3], 0.0)
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


def build_binary(lowers, uppers, max_leaf, traversal_cost, threads=None, device="cpu") -> Tree:
    """The binary tree, built level by level (module docstring); node ids are assigned in level order. The
    kernels' passes over the primitives run on `device`; what a level reads back is a few values a range."""
    if not 1 <= max_leaf <= MAX_LEAF_SIZE:
        raise ValueError(f"max_leaf must be in [1, {MAX_LEAF_SIZE}], got {max_leaf}")
    lowers = np.asarray(lowers, dtype=np.float64).reshape(-1, 3)
    uppers = np.asarray(uppers, dtype=np.float64).reshape(-1, 3)
    m = len(lowers)
    order = np.arange(m, dtype=np.int64)
    if m == 0:
        empty = np.zeros((0, 2, 3), np.float32)
        return Tree(order, empty, empty, np.zeros((0, 2), np.int32), 0, np.zeros(0, np.int64))
    if m == 1:
        lo = np.stack([lowers[0], np.full(3, EMPTY_BOX)])[None]
        hi = np.stack([uppers[0], np.full(3, EMPTY_BOX)])[None]
        child = np.array([[leaf_code(0, 1), leaf_code(0, 0)]], dtype=np.int32)
        return Tree(order, round_down(lo), round_up(hi), child, 1, np.zeros(1, np.int64))
    if m >= 2**31:
        raise ValueError(f"at most 2**31 - 1 boxes, got {m}")

    # The primitives' indices and boxes, kept in the order of `order` as the ranges are partitioned, so that
    # every pass over a range reads contiguous memory.
    prims = _primitives(np.arange(m, dtype=np.int32), lowers, uppers, device)
    scratch = _primitives(np.empty(m, dtype=np.int32), np.empty((m, 3)), np.empty((m, 3)), device)
    slots, refs, slot_boxes = [], [], []
    num_nodes = 1
    levels = [np.zeros(1, np.int64)]
    # SAH splits down to this depth; median splits below it need at most log2(M) more levels.
    sah_depth = MAX_DEPTH - math.ceil(math.log2(m))
    # The ranges of `order` placed at this level of the tree: start, count, and the parent slot
    # (node, side) that refers to each (the root, always an interior node, has none).
    start = np.array([0], dtype=np.int64)
    count = np.array([m], dtype=np.int64)
    slot = np.array([[-1, 0]])
    depth = 0
    while len(start):
        k = len(start)
        # More bins than primitives would not help, and the deep levels hold many small ranges.
        nb = int(np.clip(count.max(), 2, BINS))
        wp_start = wp.array(start.astype(np.int32), dtype=wp.int32, device=device)
        wp_count = wp.array(count.astype(np.int32), dtype=wp.int32, device=device)
        out = {name: wp.empty(k, dtype=dtype, device=device) for name, dtype in _SPLIT_OUTPUTS}
        _launch(
            _best_splits_kernel, k, [prims.lowers, prims.uppers, wp_start, wp_count, nb, *out.values()], threads, device
        )
        box_lo, box_hi = out["box_lo"].numpy(), out["box_hi"].numpy()
        extent = out["c_extent"].numpy()
        best_cost = out["cost"].numpy()
        area = half_area(np.concatenate([box_lo.T, -box_hi.T]))
        is_root = slot[:, 0] < 0
        leaf, median, split, node_id, num_nodes = level_nodes(
            count, best_cost, area, is_root, max_leaf, traversal_cost, depth, sah_depth, num_nodes, levels
        )
        # What the parents' slots hold: this range's box, and its node or leaf.
        has_parent = ~is_root
        slots.append(slot[has_parent])
        slot_boxes.append((box_lo[has_parent], box_hi[has_parent]))
        refs.append(np.where(leaf, leaf_code(start, count), node_id)[has_parent])

        # Partition the ranges that split, left side first: by bin for a binned split (stable, in the kernel),
        # by the centre for a median split.
        mode = np.where(leaf, 0, np.where(median, 2, 1)).astype(np.int32)
        n_left = wp.zeros(k, dtype=wp.int32, device=device)
        _launch(
            _partition_kernel,
            k,
            [
                prims,
                wp_start,
                wp_count,
                wp.array(mode, dtype=wp.int32, device=device),
                out["axis"],
                out["bin"],
                out["c_lo"],
                out["c_extent"],
                nb,
                scratch,
                n_left,
            ],
            threads,
            device,
        )
        n_left = n_left.numpy().astype(np.int64)
        medians = np.flatnonzero(median)
        if len(medians):
            _median_partition(prims, start[medians], count[medians], np.argmax(extent[medians], axis=1))
            n_left[medians] = count[medians] // 2

        s, n_left = start[split], n_left[split]
        start = np.concatenate([s, s + n_left])
        count = np.concatenate([n_left, count[split] - n_left])
        side = np.repeat([0, 1], len(split))
        slot = np.column_stack([np.tile(node_id[split], 2), side])
        depth += 1

    order = prims.index.numpy().astype(np.int64)
    slot = np.concatenate(slots)
    lo = np.zeros((num_nodes, 2, 3))
    hi = np.zeros((num_nodes, 2, 3))
    child = np.zeros((num_nodes, 2), dtype=np.int64)
    lo[slot[:, 0], slot[:, 1]] = np.concatenate([b[0] for b in slot_boxes])
    hi[slot[:, 0], slot[:, 1]] = np.concatenate([b[1] for b in slot_boxes])
    child[slot[:, 0], slot[:, 1]] = np.concatenate(refs)
    return Tree(order, round_down(lo), round_up(hi), child.astype(np.int32), depth - 1, np.concatenate(levels))


def level_nodes(count, best_cost, area, is_root, max_leaf, traversal_cost, depth, sah_depth, num_nodes, levels):
    """Which ranges of a level become leaves and which split at the median (the others at their best binned
    split), the splitting ones' indices and node ids, and the node count after them; appends their depths to
    `levels`."""
    split_cost = traversal_cost + best_cost / np.where(area > 0, area, 1.0)
    leaf = ~is_root & ((count == 1) | ((count <= max_leaf) & (count <= split_cost)))
    median = ~leaf & (~np.isfinite(best_cost) | (depth >= sah_depth))
    split = np.flatnonzero(~leaf)
    node_id = np.full(len(count), -1, dtype=np.int64)
    node_id[split] = 0 if depth == 0 else num_nodes + np.arange(len(split))
    num_nodes += 0 if depth == 0 else len(split)
    if depth > 0:
        levels.append(np.full(len(split), depth))
    return leaf, median, split, node_id, num_nodes


def _launch(kernel, k, inputs, threads, device):
    """One thread per range; on the CPU the levels with few ranges (the top ones, and every level of a small
    tree) in one launch, where a thread pool would cost more than it saves."""
    if k < PARALLEL_RANGES or not wp.get_device(device).is_cpu:
        wp.launch(kernel, dim=k, inputs=[*inputs, 0], device=device)
    else:
        launch_ranges(kernel, k, inputs, threads=threads, device=device)


def _median_partition(prims, start, count, axis):
    """Each range sorted by its primitives' centres along its axis (stable), in place: the first count // 2 are
    the left side. In NumPy (rare: module docstring), on views of CPU arrays or on copies of a GPU's."""
    rid = np.repeat(np.arange(len(start)), count)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    pos = start[rid] + np.arange(len(rid)) - first[rid]
    arrays = (prims.index, prims.lowers, prims.uppers)
    index, lowers, uppers = (a.numpy() for a in arrays)
    centre = (lowers[pos, axis[rid]] + uppers[pos, axis[rid]]) / 2
    sort = pos[np.lexsort((centre, rid))]
    index[pos], lowers[pos], uppers[pos] = index[sort], lowers[sort], uppers[sort]
    if not prims.index.device.is_cpu:
        for a, values in zip(arrays, (index, lowers, uppers)):
            a.assign(values)


def _widen(tree: Tree, width: int) -> Tree:
    """The `width`-wide tree (4 or 8) of a binary one: its nodes at depths that are multiples of log2(width), each
    with its descendants that many levels down as children (or a leaf met on the way, in the slot its subtree
    would have had: the children keep the binary tree's left-to-right order)."""
    levels = width.bit_length() - 1
    n = len(tree.child)
    if n == 0:
        empty = np.zeros((0, width, 3), np.float32)
        return Tree(tree.order, empty, empty.copy(), np.zeros((0, width), np.int32), 0, tree.level)
    keep = np.flatnonzero(tree.level % levels == 0)
    index = np.full(n, -1, dtype=np.int64)
    index[keep] = np.arange(len(keep))
    lo = tree.lo[keep]
    hi = tree.hi[keep]
    child = tree.child[keep].astype(np.int64)
    # Each pass doubles the slots: slot s becomes slots 2s and 2s + 1, an interior child's two children, or a leaf
    # child and an empty slot.
    for _ in range(levels - 1):
        k = len(keep)
        slots = child.shape[1]
        lo2 = np.full((k, 2 * slots, 3), EMPTY_BOX, dtype=np.float32)
        hi2 = np.full((k, 2 * slots, 3), EMPTY_BOX, dtype=np.float32)
        child2 = np.full((k, 2 * slots), leaf_code(0, 0), dtype=np.int64)
        for s in range(slots):
            c = child[:, s]
            inner = c >= 0
            lo2[~inner, 2 * s] = lo[~inner, s]
            hi2[~inner, 2 * s] = hi[~inner, s]
            child2[~inner, 2 * s] = c[~inner]
            for grand in (0, 1):
                lo2[inner, 2 * s + grand] = tree.lo[c[inner], grand]
                hi2[inner, 2 * s + grand] = tree.hi[c[inner], grand]
                child2[inner, 2 * s + grand] = tree.child[c[inner], grand]
        lo, hi, child = lo2, hi2, child2
    child = np.where(child >= 0, index[np.maximum(child, 0)], child)
    depth = -(-tree.depth // levels)
    return Tree(tree.order, lo, hi, child.astype(np.int32), depth, tree.level[keep] // levels)


# Per-bin values of all three axes (axis · BINS + bin).
BinValues = wp.types.vector(length=3 * BINS, dtype=wp.float64)
BinCounts = wp.types.vector(length=3 * BINS, dtype=wp.int32)
_SPLIT_OUTPUTS = (
    ("box_lo", wp.vec3d),
    ("box_hi", wp.vec3d),
    ("c_lo", wp.vec3d),
    ("c_extent", wp.vec3d),
    ("cost", wp.float64),
    ("axis", wp.int32),
    ("bin", wp.int32),
)


@wp.struct
class _Primitives:
    """Primitive indices and their boxes, in one order."""

    index: wp.array(dtype=wp.int32)
    lowers: wp.array(dtype=wp.vec3d)
    uppers: wp.array(dtype=wp.vec3d)


def _primitives(index, lowers, uppers, device) -> _Primitives:
    prims = _Primitives()
    prims.index = wp.array(index, dtype=wp.int32, device=device)
    prims.lowers = wp.array(lowers, dtype=wp.vec3d, device=device)
    prims.uppers = wp.array(uppers, dtype=wp.vec3d, device=device)
    return prims


@wp.func
def _area(lo: wp.vec3d, hi: wp.vec3d):
    """Half the surface area of a box; 0 for an empty one (lo = +inf, hi = −inf)."""
    zero = wp.float64(0.0)
    dx = wp.max(hi[0] - lo[0], zero)
    dy = wp.max(hi[1] - lo[1], zero)
    dz = wp.max(hi[2] - lo[2], zero)
    return dx * dy + dy * dz + dz * dx


@wp.func
def _bin_scale(extent: wp.float64, nb: int):
    """Bins per unit length, for nb bins over a centre extent (0 when the extent is: all in bin 0)."""
    scale = wp.float64(0.0)
    if extent > wp.float64(0.0):
        scale = wp.float64(nb) / extent
    return scale


@wp.func
def _bin_of(c: wp.float64, c_lo: wp.float64, scale: wp.float64, nb: int):
    """The bin of a centre coordinate among nb from c_lo on."""
    return wp.clamp(int((c - c_lo) * scale), 0, nb - 1)


@wp.kernel
def _best_splits_kernel(
    lowers: wp.array(dtype=wp.vec3d),
    uppers: wp.array(dtype=wp.vec3d),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    nb: int,
    box_lo: wp.array(dtype=wp.vec3d),
    box_hi: wp.array(dtype=wp.vec3d),
    c_lo_out: wp.array(dtype=wp.vec3d),
    c_extent_out: wp.array(dtype=wp.vec3d),
    cost_out: wp.array(dtype=wp.float64),
    axis_out: wp.array(dtype=wp.int32),
    bin_out: wp.array(dtype=wp.int32),
    first_range: int,
):
    """Per range: its box, its centres' extent, and its least-cost binned split: the sum over the two sides of
    box area × count, inf where no split separates any two centres; the axis and the last bin of the left side.
    One thread per range, two passes over its primitives (bounds, then the bins of all three axes)."""
    r = wp.tid() + first_range
    first = int(start[r])
    end = first + int(count[r])
    inf = wp.float64(wp.inf)
    half = wp.float64(0.5)
    lo = wp.vec3d(inf, inf, inf)
    hi = wp.vec3d(-inf, -inf, -inf)
    c_lo = wp.vec3d(inf, inf, inf)
    c_hi = wp.vec3d(-inf, -inf, -inf)
    for i in range(first, end):
        a = lowers[i]
        b = uppers[i]
        lo = wp.min(lo, a)
        hi = wp.max(hi, b)
        c = (a + b) * half
        c_lo = wp.min(c_lo, c)
        c_hi = wp.max(c_hi, c)
    extent = c_hi - c_lo
    box_lo[r] = lo
    box_hi[r] = hi
    c_lo_out[r] = c_lo
    c_extent_out[r] = extent

    n_bin = BinCounts()
    lx = BinValues()
    ly = BinValues()
    lz = BinValues()
    hx = BinValues()
    hy = BinValues()
    hz = BinValues()
    for j in range(3 * BINS):
        lx[j] = inf
        ly[j] = inf
        lz[j] = inf
        hx[j] = -inf
        hy[j] = -inf
        hz[j] = -inf
    scale = wp.vec3d(_bin_scale(extent[0], nb), _bin_scale(extent[1], nb), _bin_scale(extent[2], nb))
    for i in range(first, end):
        a = lowers[i]
        b = uppers[i]
        c = (a + b) * half
        for axis in range(3):
            j = axis * BINS + _bin_of(c[axis], c_lo[axis], scale[axis], nb)
            n_bin[j] = n_bin[j] + 1
            lx[j] = wp.min(lx[j], a[0])
            ly[j] = wp.min(ly[j], a[1])
            lz[j] = wp.min(lz[j], a[2])
            hx[j] = wp.max(hx[j], b[0])
            hy[j] = wp.max(hy[j], b[1])
            hz[j] = wp.max(hz[j], b[2])

    best_cost = inf
    best_axis = int(0)
    best_bin = int(0)
    right_area = BinValues()
    right_n = BinCounts()
    for axis in range(3):
        base = axis * BINS
        # Right side of the split after bin j: bins j+1..nb−1, swept from the last bin.
        r_lo = wp.vec3d(inf, inf, inf)
        r_hi = wp.vec3d(-inf, -inf, -inf)
        m = int(0)
        for step in range(nb - 1):
            j = base + nb - 1 - step
            r_lo = wp.min(r_lo, wp.vec3d(lx[j], ly[j], lz[j]))
            r_hi = wp.max(r_hi, wp.vec3d(hx[j], hy[j], hz[j]))
            m += n_bin[j]
            right_area[j - 1] = _area(r_lo, r_hi)
            right_n[j - 1] = m
        l_lo = wp.vec3d(inf, inf, inf)
        l_hi = wp.vec3d(-inf, -inf, -inf)
        m = int(0)
        axis_cost = inf
        axis_bin = int(0)
        for split in range(nb - 1):
            j = base + split
            l_lo = wp.min(l_lo, wp.vec3d(lx[j], ly[j], lz[j]))
            l_hi = wp.max(l_hi, wp.vec3d(hx[j], hy[j], hz[j]))
            m += n_bin[j]
            cost = inf
            if m > 0 and right_n[j] > 0:
                cost = _area(l_lo, l_hi) * wp.float64(m) + right_area[j] * wp.float64(right_n[j])
            if cost < axis_cost:
                axis_cost = cost
                axis_bin = split
        if axis_cost < best_cost:
            best_cost = axis_cost
            best_axis = axis
            best_bin = axis_bin
    cost_out[r] = best_cost
    axis_out[r] = best_axis
    bin_out[r] = best_bin


@wp.kernel
def _partition_kernel(
    prims: _Primitives,
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    mode: wp.array(dtype=wp.int32),
    axis: wp.array(dtype=wp.int32),
    split_bin: wp.array(dtype=wp.int32),
    c_lo: wp.array(dtype=wp.vec3d),
    extent: wp.array(dtype=wp.vec3d),
    nb: int,
    scratch: _Primitives,
    n_left: wp.array(dtype=wp.int32),
    first_range: int,
):
    """Ranges of mode 1 (a binned split) reordered in place, stably: the primitives whose centre's bin is at most
    the split bin first; their number in n_left. Other ranges (leaves, median splits) are left alone."""
    r = wp.tid() + first_range
    if mode[r] != 1:
        return
    first = int(start[r])
    end = first + int(count[r])
    k = axis[r]
    lo = c_lo[r][k]
    scale = _bin_scale(extent[r][k], nb)
    b = split_bin[r]
    half = wp.float64(0.5)
    w = first
    for side in range(2):
        for i in range(first, end):
            right = wp.where(_bin_of((prims.lowers[i][k] + prims.uppers[i][k]) * half, lo, scale, nb) > b, 1, 0)
            if right == side:
                scratch.index[w] = prims.index[i]
                scratch.lowers[w] = prims.lowers[i]
                scratch.uppers[w] = prims.uppers[i]
                w += 1
        if side == 0:
            n_left[r] = w - first
    for i in range(first, end):
        prims.index[i] = scratch.index[i]
        prims.lowers[i] = scratch.lowers[i]
        prims.uppers[i] = scratch.uppers[i]


def round_down(x):
    """float32 values <= x (boxes must only grow when stored in float32)."""
    y = x.astype(np.float32)
    return np.where(y > x, np.nextafter(y, np.float32(-np.inf)), y)


def round_up(x):
    y = x.astype(np.float32)
    return np.where(y < x, np.nextafter(y, np.float32(np.inf)), y)
