"""A bounding volume hierarchy over axis-aligned boxes, built in NumPy and traversed in Warp kernels.

Layout
------
`build_bvh` returns a `Tree` of flat arrays, ready to become Warp arrays; `width` is 2 (binary) or 4:

* `order` (M,): the primitives in leaf order. Every leaf covers a contiguous range of it, so the caller
  stores its per-primitive data in this order and a leaf reads one contiguous block.
* `lo`, `hi` (N, width, 3) float32: node k holds the boxes of its children, not its own, so that one node
  fetch tests all its children and the traversal can visit the nearest first.
* `child` (N, width) int32: a child >= 0 is an interior node; a child < 0 is a leaf, `leaf_range(child)` =
  (start, count) into `order`, count <= `MAX_LEAF_SIZE`.

Node 0 is the root. Unused child slots (a 4-wide node may have only 2 or 3 children, a one-primitive tree has
one) are empty leaves (count 0) in a box at 1e30 in every coordinate: no ray of unit direction gets there
before t ≈ 1e30, and one that does finds nothing. An empty set has no nodes at all and must not be traversed.

Construction
------------
The binary tree is built top down, one level at a time so that every step is a NumPy operation over all the
nodes of the level: each node's primitives are binned by box centre along each axis (`BINS` bins over the
centres' extent), and the node is split at the bin boundary of least surface area heuristic (SAH) cost, the
area of each side's box times its number of primitives. A node becomes a leaf when it holds at most
`max_leaf` primitives and the heuristic prefers that to splitting. Nodes whose centres all fall in one bin,
and all nodes once the tree is deep enough that SAH splits could exceed `MAX_DEPTH`, are split at the median
instead, so the depth never exceeds MAX_DEPTH interior nodes.

The 4-wide tree collapses the binary one: its nodes are the binary nodes at even depth, and their children
are their binary grandchildren (or a child itself, where that is a leaf).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# Bits of a leaf code that hold the primitive count.
LEAF_BITS = 3
MAX_LEAF_SIZE = (1 << LEAF_BITS) - 1
BINS = 16
# Most interior nodes on any root-to-leaf path of the binary tree (MAX_DEPTH / 2 in the 4-wide one), which
# bounds what a traversal stack must hold.
MAX_DEPTH = 40
# Cost of testing a node's child boxes, relative to one primitive test.
TRAVERSAL_COST = 1.0
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


def build_bvh(lowers, uppers, max_leaf: int = 4, width: int = 2, traversal_cost: float = TRAVERSAL_COST) -> Tree:
    """The tree of the given `width` (2 or 4) over the boxes (lowers, uppers) (M, 3); see the module docstring."""
    if width not in (2, 4):
        raise ValueError(f"width must be 2 or 4, got {width}")
    tree = _build_binary(lowers, uppers, max_leaf, traversal_cost)
    return tree if width == 2 else _widen(tree)


def _half_area(box):
    """Half the surface area of boxes stored as (lo, −hi) along the first axis (6, ...); 0 for empty ones."""
    d = np.maximum(-box[3:] - box[:3], 0.0)
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


def _build_binary(lowers, uppers, max_leaf, traversal_cost) -> Tree:
    """The binary tree, built level by level (module docstring); node ids are assigned in level order."""
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
        return Tree(order, _round_down(lo), _round_up(hi), child, 1, np.zeros(1, np.int64))

    # Boxes as six rows (lo, −hi), so that one minimum reduces both corners; centres as three rows.
    boxes = np.ascontiguousarray(np.concatenate([lowers.T, -uppers.T]))
    centres = np.ascontiguousarray((lowers + uppers).T / 2)
    slots, refs, slot_boxes = [], [], []
    num_nodes = 1
    levels = [np.zeros(1, np.int64)]
    # SAH splits down to this depth; median splits below it need at most log2(M) more levels.
    sah_depth = MAX_DEPTH - math.ceil(math.log2(m))
    # The ranges of `order` placed at this level of the tree: start, count, and the parent slot
    # (node, side) that refers to each (the root, always an interior node, has none).
    start = np.array([0])
    count = np.array([m])
    slot = np.array([[-1, 0]])
    depth = 0
    while len(start):
        k = len(start)
        first = np.concatenate([[0], np.cumsum(count)[:-1]])
        rid = np.repeat(np.arange(k), count)
        pos = start[rid] + np.arange(len(rid)) - first[rid]
        prims = order[pos]
        box = boxes[:, prims]
        c = centres[:, prims]
        range_box = np.minimum.reduceat(box, first, axis=1)
        c_lo = np.minimum.reduceat(c, first, axis=1)
        extent = np.maximum.reduceat(c, first, axis=1) - c_lo

        bins, best_cost, best_axis, best_bin = _best_splits(box, c, c_lo, extent, rid, count)
        area = _half_area(range_box)
        split_cost = traversal_cost + best_cost / np.where(area > 0, area, 1.0)
        is_root = slot[:, 0] < 0
        leaf = ~is_root & ((count == 1) | ((count <= max_leaf) & (count <= split_cost)))
        median = ~leaf & (~np.isfinite(best_cost) | (depth >= sah_depth))

        split = np.flatnonzero(~leaf)
        node_id = np.full(k, -1, dtype=np.int64)
        node_id[split] = 0 if depth == 0 else num_nodes + np.arange(len(split))
        num_nodes += 0 if depth == 0 else len(split)
        if depth > 0:
            levels.append(np.full(len(split), depth))
        # What the parents' slots hold: this range's box, and its node or leaf.
        has_parent = ~is_root
        slots.append(slot[has_parent])
        slot_boxes.append(range_box[:, has_parent])
        refs.append(np.where(leaf, leaf_code(start, count), node_id)[has_parent])

        # Partition the ranges that split, left side first: by bin for a binned split (stable), by the
        # centre for a median split.
        elements = np.arange(len(rid))
        axis = np.where(median, np.argmax(extent, axis=0), best_axis)[rid]
        goes_right = bins[axis, elements] > best_bin[rid]
        key = np.where(median[rid], c[axis, elements], goes_right)
        sort = np.lexsort((key, rid))
        splitting = ~leaf[rid]
        sort = sort[splitting[sort]]
        order[pos[splitting]] = prims[sort]
        n_left = np.where(median, count // 2, np.bincount(rid, weights=~goes_right, minlength=k).astype(np.int64))

        s, n_left = start[split], n_left[split]
        start = np.concatenate([s, s + n_left])
        count = np.concatenate([n_left, count[split] - n_left])
        side = np.repeat([0, 1], len(split))
        slot = np.column_stack([np.tile(node_id[split], 2), side])
        depth += 1

    slot = np.concatenate(slots)
    box = np.concatenate(slot_boxes, axis=1)
    lo = np.zeros((num_nodes, 2, 3))
    hi = np.zeros((num_nodes, 2, 3))
    child = np.zeros((num_nodes, 2), dtype=np.int64)
    lo[slot[:, 0], slot[:, 1]] = box[:3].T
    hi[slot[:, 0], slot[:, 1]] = -box[3:].T
    child[slot[:, 0], slot[:, 1]] = np.concatenate(refs)
    return Tree(order, _round_down(lo), _round_up(hi), child.astype(np.int32), depth - 1, np.concatenate(levels))


def _widen(tree: Tree) -> Tree:
    """The 4-wide tree of a binary one: its nodes at even depth, each with its grandchildren as children."""
    n = len(tree.child)
    if n == 0:
        return Tree(tree.order, np.zeros((0, 4, 3), np.float32), np.zeros((0, 4, 3), np.float32),
                    np.zeros((0, 4), np.int32), 0, tree.level)
    keep = np.flatnonzero(tree.level % 2 == 0)
    index = np.full(n, -1, dtype=np.int64)
    index[keep] = np.arange(len(keep))
    lo = np.full((len(keep), 4, 3), EMPTY_BOX, dtype=np.float32)
    hi = np.full((len(keep), 4, 3), EMPTY_BOX, dtype=np.float32)
    child = np.full((len(keep), 4), leaf_code(0, 0), dtype=np.int64)
    for side in (0, 1):
        c = tree.child[keep, side].astype(np.int64)
        inner = c >= 0
        # A leaf child keeps its slot; an interior child hands over its own two children.
        lo[~inner, 2 * side] = tree.lo[keep[~inner], side]
        hi[~inner, 2 * side] = tree.hi[keep[~inner], side]
        child[~inner, 2 * side] = c[~inner]
        for grand in (0, 1):
            lo[inner, 2 * side + grand] = tree.lo[c[inner], grand]
            hi[inner, 2 * side + grand] = tree.hi[c[inner], grand]
            child[inner, 2 * side + grand] = tree.child[c[inner], grand]
    child = np.where(child >= 0, index[np.maximum(child, 0)], child)
    return Tree(tree.order, lo, hi, child.astype(np.int32), (tree.depth + 1) // 2, tree.level[keep] // 2)


def _best_splits(box, c, c_lo, extent, rid, count):
    """The least-cost binned split of each range: (bins (3, E) of the elements, cost (k,) — the sum over the
    two sides of box area × count, inf where no split separates any two centres —, axis (k,), last bin of the
    left side (k,))."""
    k = len(count)
    # More bins than primitives would not help, and the deep levels hold many small ranges.
    nb = int(np.clip(count.max(), 2, BINS))
    scale = np.where(extent > 0, nb / np.where(extent > 0, extent, 1.0), 0.0)
    bins = np.clip(((c - c_lo[:, rid]) * scale[:, rid]).astype(np.int64), 0, nb - 1)
    best_cost = np.full(k, np.inf)
    best_axis = np.zeros(k, dtype=np.int64)
    best_bin = np.zeros(k, dtype=np.int64)
    for axis in range(3):
        # Per bin and range, laid out (bin, range) so that the scans over the bins run along long rows.
        key = bins[axis] * k + rid
        n_bin = np.bincount(key, minlength=nb * k).reshape(nb, k)
        bin_box = np.full((6, nb * k), np.inf)
        for row in range(6):
            np.minimum.at(bin_box[row], key, box[row])
        bin_box = bin_box.reshape(6, nb, k)
        # Split after bin j: left = bins 0..j, right = bins j+1..nb−1.
        left_area = _half_area(np.minimum.accumulate(bin_box, axis=1))[:-1]
        right_area = _half_area(np.minimum.accumulate(bin_box[:, ::-1], axis=1))[-2::-1]
        left_n = np.cumsum(n_bin, axis=0)[:-1]
        right_n = count - left_n
        cost = np.where((left_n > 0) & (right_n > 0), left_area * left_n + right_area * right_n, np.inf)
        j = np.argmin(cost, axis=0)
        axis_cost = cost[j, np.arange(k)]
        better = axis_cost < best_cost
        best_cost = np.where(better, axis_cost, best_cost)
        best_axis = np.where(better, axis, best_axis)
        best_bin = np.where(better, j, best_bin)
    return bins, best_cost, best_axis, best_bin


def _round_down(x):
    """float32 values <= x (boxes must only grow when stored in float32)."""
    y = x.astype(np.float32)
    return np.where(y > x, np.nextafter(y, np.float32(-np.inf)), y)


def _round_up(x):
    y = x.astype(np.float32)
    return np.where(y < x, np.nextafter(y, np.float32(np.inf)), y)
