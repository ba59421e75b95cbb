"""The lat-long map as Cycles reads it through benchmarks/cycles_peer.py's translation (opt-in: `pytest -m bpy`).

The camera sees nothing but the map: a few large cells of distinct colours, looked at obliquely through a wide
lens, so that a mirrored u, a flipped v, a turn about the up axis or another up axis would put other colours in
most pixels. Both renderers average each pixel's footprint (a box filter), so away from cell edges the pixels
are the cells' colours exactly and near them the same averages up to sampling noise.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from warp_hair.io import write_exr
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.bpy
@pytest.mark.parametrize("target", [(1.0, 0.4, -1.0), (-0.3, -0.6, 1.0)])
def test_cycles_sees_the_map_where_warp_hair_does(tmp_path, target):
    bpy = pytest.importorskip("bpy", reason="bpy 4.5 (Python 3.11) is the `blender` extra")
    sys.path.insert(0, str(BENCHMARKS))
    try:
        from cycles_peer import render_cycles
    finally:
        sys.path.remove(str(BENCHMARKS))
    cells = np.random.default_rng(7).uniform(0.05, 1.0, (4, 8, 3)).astype(np.float32)
    write_exr(tmp_path / "map.exr", np.kron(cells, np.ones((8, 8, 1), np.float32)))  # 64×32, 8×8-pixel cells
    scene = scene_from_dict(
        {
            "camera": {
                "type": "perspective",
                # Beyond the fiber at the origin, looking away from it.
                "origin": [3.0 * t for t in target],
                "target": [4.0 * t for t in target],
                "up": [0.0, 1.0, 0.0],
                "fov": 100.0,
                "resolution": [32, 32],
            },
            "lights": [{"type": "environment", "file": "map.exr"}],
            # One short fiber at the origin, behind the camera: the scene needs fibers.
            "fibers": {"generator": "swatch", "count": 1, "layers": 1, "length": 0.01, "radius": 0.001},
            "hair": {"albedo": [0.5, 0.5, 0.5]},
            "render": {"spp": 64, "max_depth": 1},
        },
        base_dir=tmp_path,
    )
    ours = render(scene, threads=2)
    theirs = render_cycles(bpy, scene, 64, threads=2)
    difference = np.abs(ours - theirs).max(axis=2)
    # Pixels inside one cell agree to float precision; those across a cell edge to the footprint's sampling.
    assert np.mean(difference < 1e-4) > 0.5
    assert np.mean(difference) < 0.02 * float(theirs.mean())
    np.testing.assert_allclose(ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1)), rtol=0.01)
