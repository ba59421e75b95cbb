"""How much light a depth limit loses: the mean of the standard swatch at several max_depth, relative to 256.

    python benchmarks/depth.py [--resolution 48] [--spp 256]

Light hair keeps its energy through many bounces between fibers; this is the table behind the README's
choice of default depth (64, with Russian roulette from bounce 8).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from warp_hair.cli import exit_on_interrupt
from warp_hair.model.params import HairParams
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

SCENE = Path(__file__).with_name("standard_swatch.toml")
DEPTHS = (4, 8, 16, 32, 64, 256)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=48)
    parser.add_argument("--spp", type=int, default=256)
    args = parser.parse_args()
    scene = load_scene(SCENE)
    scene.camera = dataclasses.replace(scene.camera, resolution=(args.resolution, args.resolution))
    materials = {"blonde, albedo 0.9": HairParams(albedo=0.9), "benchmark hair": scene.hair}
    print(f"image mean relative to depth {DEPTHS[-1]} ({args.resolution}² px, {args.spp} spp, same seed)")
    for name, hair in materials.items():
        scene.hair = hair
        means, seconds = [], []
        for depth in DEPTHS:
            scene.render = dataclasses.replace(scene.render, max_depth=depth)
            start = time.perf_counter()
            means.append(render(scene, spp=args.spp, seed=1).mean())
            seconds.append(time.perf_counter() - start)
        cells = [f"depth {d}: {m / means[-1] - 1:+.2%} ({s:.1f} s)" for d, m, s in zip(DEPTHS, means, seconds)]
        print(f"{name:20s} " + "  ".join(cells))


if __name__ == "__main__":
    exit_on_interrupt(main)
