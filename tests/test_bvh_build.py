"""The BVH build in Warp kernels reproduces the NumPy reference build (tests/helpers/reference_bvh.py) exactly: the same
order, boxes, children and levels, so the same surface area heuristic cost and the same traversals; and the tree
does not depend on the number of threads."""

from pathlib import Path

import numpy as np
import pytest
from helpers import reference_bvh

from warp_hair.geometry import bvh
from warp_hair.geometry.formats import load_fibers
from warp_hair.geometry.generators import wavy
from warp_hair.geometry.tubes import segment_boxes, segment_frames

BENCH_FIBERS = Path(__file__).parents[1] / "benchmarks" / "standard_swatch_fibers.txt"


def tube_boxes(assembly):
    p0, p1, r0, r1, strand, _ = assembly.segments()
    return segment_boxes(segment_frames(p0, p1, r0, r1, strand))


def boxes(case):
    rng = np.random.default_rng(4)
    if case == "swatch":
        return tube_boxes(load_fibers(BENCH_FIBERS))
    if case == "wavy":
        return tube_boxes(wavy(count=300, layers=3, length=0.5, amplitude=0.02, wavelength=0.1, seed=2))
    if case == "geometric":  # lopsided SAH splits: deep enough for the median splits below sah_depth
        x = 1.03 ** np.arange(2000)
        lowers = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
        return lowers, lowers + np.column_stack([0.2 * x, np.ones_like(x), np.ones_like(x)])
    if case == "coincident":  # all centres in one bin: median splits
        c = np.zeros((50, 3))
        return c - rng.uniform(0.01, 0.2, (50, 3)), c + rng.uniform(0.01, 0.2, (50, 3))
    if case == "clustered":  # a few coincident clusters among random boxes
        c = np.concatenate([rng.normal(size=(200, 3)), np.repeat(rng.normal(size=(5, 3)), 20, axis=0)])
        return c - rng.uniform(0.0, 0.1, c.shape), c + rng.uniform(0.0, 0.1, c.shape)
    m = {"two": 2, "three": 3, "random": 500}[case]
    c = rng.normal(size=(m, 3))
    return c - rng.uniform(0.01, 0.2, (m, 3)), c + rng.uniform(0.01, 0.2, (m, 3))


def assert_same_tree(a, b):
    for field in a._fields:
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.mark.parametrize("case", ["two", "three", "random", "coincident", "clustered", "geometric", "swatch", "wavy"])
def test_warp_build_is_the_numpy_reference(case):
    lowers, uppers = boxes(case)
    for max_leaf, cost in ((1, 1.0), (2, 1.0), (4, 0.5)):
        expected = reference_bvh.build_binary(lowers, uppers, max_leaf, cost)
        assert_same_tree(bvh.build_binary(lowers, uppers, max_leaf, cost), expected)


def test_threads_do_not_change_the_tree():
    lowers, uppers = boxes("wavy")
    one = bvh.build_bvh(lowers, uppers, max_leaf=2, width=4, threads=1)
    for threads in (2, 3):
        assert_same_tree(bvh.build_bvh(lowers, uppers, max_leaf=2, width=4, threads=threads), one)
