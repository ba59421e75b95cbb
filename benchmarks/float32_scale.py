"""How far from the origin float32 still resolves a fiber: the brown_wavy front view moved away along x.

    python benchmarks/float32_scale.py [--spp 64] [--shifts 1 10 100 400 1000]

Fibers and camera are translated together, so the image should not change; the table gives the image mean
relative to the untranslated one, against the ratio of the scene's extent to the fiber radius (what
warp_hair.validate.RESOLUTION_LIMIT bounds), beside the seed-to-seed noise of that mean.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import importlib
import tomllib
from pathlib import Path

import numpy as np

from warp_hair.cli import exit_on_interrupt
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict
from warp_hair.validate import RESOLUTION_LIMIT

SCENE = Path(__file__).resolve().parents[1] / "targets" / "brown_wavy" / "scene_front.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--shifts", type=float, nargs="+", default=[1.0, 10.0, 100.0, 400.0, 1000.0])
    args = parser.parse_args()
    base = tomllib.loads(SCENE.read_text())
    scene = scene_from_dict(base, base_dir=SCENE.parent)
    reference = render(scene, spp=args.spp).mean()
    noise = render(scene, spp=args.spp, seed=scene.render.seed + 1).mean() / reference - 1
    radius = float(scene.fibers.radii.min())
    points = np.asarray(scene.fibers.points, dtype=np.float64)
    print(f"brown_wavy front, {args.spp} spp; seed-to-seed change of the mean: {100 * noise:+.1f}%")
    print("| shift | extent / radius | mean relative to unshifted | the scene check |")
    print("| --- | --- | --- | --- |")
    # Measured without the check, to show what it prevents.
    importlib.import_module("warp_hair.renderer.prepare").check_scene = lambda scene: None
    for shift in args.shifts:
        moved = copy.copy(scene)
        moved.camera = dataclasses.replace(
            scene.camera,
            origin=np.add(scene.camera.origin, [shift, 0, 0]).tolist(),
            target=np.add(scene.camera.target, [shift, 0, 0]).tolist(),
        )
        moved.fibers = FiberAssembly(points + [shift, 0.0, 0.0], scene.fibers.radii, scene.fibers.strand_offsets)
        extent = max(np.abs(moved.fibers.points).max(), *np.abs(moved.camera.origin))
        verdict = "refused" if extent > RESOLUTION_LIMIT * radius else "accepted"
        change = render(moved, spp=args.spp).mean() / reference - 1
        print(f"| {shift:g} | {extent / radius:.3g} | {100 * change:+.1f}% | {verdict} |")


if __name__ == "__main__":
    exit_on_interrupt(main)
