"""CPU and wall seconds of a render and of its gradient pass, of a prepared scene: the time a sample, without the
preparation (a fit prepares its scenes once).

    python benchmarks/time_per_sample.py [SCENE ...] [--spp 16] [--threads 1] [--reps 2] [--grad]

SCENE is a scene file or a name: `swatch` (benchmarks/standard_swatch.toml) or a shipped target's name (its
front view, e.g. brown_wavy). Each pass is run once at 1 spp first (compilation, caches), then --reps times; the
line gives the least and the median CPU seconds (time.process_time, all threads) and wall seconds, and µs of
CPU a sample (pixels × spp). On a shared machine compare CPU seconds, and runs of two versions alternated
(docs/benchmarks.md, issue 45).
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def scene_path(name: str) -> Path:
    if name == "swatch":
        return HERE / "standard_swatch.toml"
    if Path(name).suffix == ".toml":
        return Path(name)
    return HERE.parent / "targets" / name / "scene_front.toml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=["swatch", "brown_wavy"])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--grad", action="store_true", help="time render_jacobian too")
    args = parser.parse_args()

    import warp as wp

    wp.config.quiet = True
    from warp_hair.renderer.gradients import render_jacobian
    from warp_hair.renderer.prepare import prepare
    from warp_hair.renderer.render import render
    from warp_hair.scene import load_scene

    for name in args.scenes:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # interpenetration warnings of the targets' strands
            prepared = prepare(load_scene(scene_path(name)))
        width, height = prepared.resolution
        passes = [("forward", render)] + ([("gradient", render_jacobian)] if args.grad else [])
        for label, run in passes:
            run(prepared, spp=1, seed=5, threads=args.threads)
            cpu, wall = [], []
            for _ in range(args.reps):
                c0, w0 = time.process_time(), time.perf_counter()
                run(prepared, spp=args.spp, seed=5, threads=args.threads)
                cpu.append(time.process_time() - c0)
                wall.append(time.perf_counter() - w0)
            per_sample = 1e6 * min(cpu) / (width * height * args.spp)
            print(
                f"{name} {label} {args.spp} spp, {args.threads} thread(s): CPU s least {min(cpu):.3f} median "
                f"{np.median(cpu):.3f}, wall s least {min(wall):.3f} median {np.median(wall):.3f}, "
                f"{per_sample:.2f} µs CPU a sample (load {os.getloadavg()[0]:.2f})",
                flush=True,
            )


if __name__ == "__main__":
    main()
