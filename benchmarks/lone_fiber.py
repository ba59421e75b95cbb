"""Benchmark: one straight fiber, direct lighting only, against the exact answer, in warp-hair, Mitsuba 3 and
Blender Cycles.

    python benchmarks/lone_fiber.py [--spp 1024] [--columns 32] [--bounces 1]

A fiber of radius 0.05 along +y, seen head-on by an orthographic camera exactly as wide as the fiber, lit by
one directional light, one scattering vertex (no inter-reflection, no sky). Each pixel column then sees
S(wo, wi, h)·E averaged over its footprint of offsets h, which this script integrates by quadrature (64 points
a column) with `warp_hair.bsdf.eval` (itself within 1e-4 of the float64 reference in the tests). Both
renderers are compared with that quadrature: the ratio of image means, and the largest column error.

This separates the BSDF and the fiber's geometry from everything else a swatch adds (inter-reflection, the
curve shapes' joints and ends): a renderer brighter here is brighter in its single scattering. Mitsuba renders
the fiber as a `bsplinecurve` with collinear control points (a straight tube of constant radius) at α = 0,
`path` integrator with max_depth = bounces + 1 (its count of path segments); Cycles as THICK curves
(benchmarks/cycles_peer.py). Either peer is skipped, with the reason, when it is not installed.

With --bounces above 1 the exact answer is the same: the near-field model's fiber is a scattering surface whose
lobes already include every passage through it (TT, TRT, ...), and a path that leaves a lone straight fiber
never meets it again. A renderer whose image changes with the bounces scatters off the same fiber twice.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from cycles_peer import import_bpy, render_cycles
from mitsuba_peer import import_mitsuba, mitsuba_scene, time_mitsuba

import warp_hair as wh
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.formats import save_fibers
from warp_hair.parallel import default_threads
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

RADIUS = 0.05
HAIR = {"albedo": [0.55, 0.4, 0.25], "beta_m": 0.3, "beta_n": 0.35, "alpha": 0.0, "eta": 1.55}
# The direction each light travels: from the front, grazing from the side, from behind.
LIGHTS = {"front": (0.2, -0.3, -1.0), "side": (-0.8, 0.2, -0.4), "back": (0.15, -0.25, 1.0)}
QUADRATURE = 64


def lone_fiber_scene(light_direction, columns, spp, bounces=1):
    data = {
        "camera": {
            "type": "orthographic",
            "origin": [0.0, 0.0, 3.0],
            "target": [0.0, 0.0, 0.0],
            "up": [0.0, 1.0, 0.0],
            "width": 2.0 * RADIUS,
            "resolution": [columns, 4],
        },
        "lights": [{"type": "directional", "direction": list(light_direction), "irradiance": [2.0, 2.0, 2.0]}],
        "fibers": {"generator": "swatch", "count": 1, "layers": 1},
        "hair": HAIR,
        "render": {"spp": spp, "max_depth": bounces, "seed": 5},
    }
    scene = scene_from_dict(data)
    # Collinear vertices: a straight tube for us, and valid B-spline control points for Mitsuba.
    points = np.column_stack([np.zeros(9), np.linspace(-1.0, 1.0, 9), np.zeros(9)])
    scene.fibers = FiberAssembly(points, np.full(9, RADIUS), np.array([0, 9]))
    return scene


def quadrature(params, light_direction, columns):
    """Each column's mean of S·E over its footprint, the fiber's frame built from the exact cylinder."""
    to_light = -np.asarray(light_direction, dtype=np.float64)
    to_light /= np.linalg.norm(to_light)
    x = -RADIUS + (np.arange(columns * QUADRATURE) + 0.5) * 2.0 * RADIUS / (columns * QUADRATURE)
    h = x / RADIUS
    tangent = np.array([0.0, 1.0, 0.0])
    normal = np.stack([h, np.zeros_like(h), np.sqrt(1.0 - h**2)], axis=1)
    y = np.cross(normal, tangent)

    def local(w):
        return np.stack([np.full(len(h), w @ tangent), y @ w, normal @ w], axis=1)

    wo, wi = local(np.array([0.0, 0.0, 1.0])), local(to_light)
    h_frame = -wo[:, 1] / np.hypot(wo[:, 1], wo[:, 2])
    value = wh.bsdf.eval(params, wo.astype(np.float32), wi.astype(np.float32), h_frame.astype(np.float32))
    return (value.astype(np.float64) * 2.0).reshape(columns, QUADRATURE, 3).mean(axis=1)


def fmt(values, spec=".4f"):
    return "(" + ", ".join(format(v, spec) for v in values) + ")"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=1024)
    parser.add_argument("--columns", type=int, default=32)
    parser.add_argument("--bounces", type=int, default=1, help="scattering vertices a path may have (default 1)")
    args = parser.parse_args(argv)
    mi = import_mitsuba()
    bpy = import_bpy()
    with tempfile.TemporaryDirectory() as tmp:
        for name, direction in LIGHTS.items():
            scene = lone_fiber_scene(direction, args.columns, args.spp, args.bounces)
            exact = quadrature(scene.hair, direction, args.columns)
            ours = render(scene).mean(axis=0)
            line = (
                f"[{name}] exact mean {fmt(exact.mean(axis=0))}; warp-hair / exact "
                f"{fmt(ours.mean(axis=0) / exact.mean(axis=0))}"
                f", worst column {np.max(np.abs(ours - exact)) / exact.max():.2%} of the peak"
            )
            if mi is not None:
                fibers_file = Path(tmp) / "fiber.txt"
                save_fibers(scene.fibers, fibers_file)
                mi_scene = mitsuba_scene(mi, scene, args.spp, shape="bsplinecurve", fibers_file=fibers_file)
                _, _, theirs = time_mitsuba(mi, mi_scene, args.spp, 5, default_threads(), 1)
                theirs = theirs.mean(axis=0)
                line += (
                    f"; Mitsuba / exact {fmt(theirs.mean(axis=0) / exact.mean(axis=0))}, worst column "
                    f"{np.max(np.abs(theirs - exact)) / exact.max():.2%}"
                )
            if bpy is not None:
                theirs = render_cycles(bpy, scene, args.spp, threads=default_threads()).mean(axis=0)
                line += (
                    f"; Cycles / exact {fmt(theirs.mean(axis=0) / exact.mean(axis=0))}, worst column "
                    f"{np.max(np.abs(theirs - exact)) / exact.max():.2%}"
                )
            print(line)


if __name__ == "__main__":
    main()
