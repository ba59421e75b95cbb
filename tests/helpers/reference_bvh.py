"""The binned-SAH binary BVH build in NumPy, level by level: the reference the Warp-kernel build of
`warp_hair.geometry.bvh` must reproduce exactly (the same tree: order, boxes, children, levels)."""

import math

import numpy as np

from warp_hair.geometry.bvh import BINS, MAX_DEPTH, Tree, half_area, leaf_code, level_nodes, round_down, round_up


def build_binary(lowers, uppers, max_leaf, traversal_cost) -> Tree:
    """The binary tree of two or more boxes, built level by level (warp_hair.geometry.bvh's docstring); node ids are
    assigned in level order. (The build's argument checks and its trees of 0 and 1 boxes are not repeated here.)"""
    lowers = np.asarray(lowers, dtype=np.float64).reshape(-1, 3)
    uppers = np.asarray(uppers, dtype=np.float64).reshape(-1, 3)
    m = len(lowers)
    assert m >= 2
    order = np.arange(m, dtype=np.int64)

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
        area = half_area(range_box)
        is_root = slot[:, 0] < 0
        # The leaf rule and the node numbering are the build's own: what is checked is the splits.
        leaf, median, split, node_id, num_nodes = level_nodes(
            count, best_cost, area, is_root, max_leaf, traversal_cost, depth, sah_depth, num_nodes, levels
        )
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
    return Tree(order, round_down(lo), round_up(hi), child.astype(np.int32), depth - 1, np.concatenate(levels))


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
        left_area = half_area(np.minimum.accumulate(bin_box, axis=1))[:-1]
        right_area = half_area(np.minimum.accumulate(bin_box[:, ::-1], axis=1))[-2::-1]
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
