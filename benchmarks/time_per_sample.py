"""CPU and wall seconds of a render and of its gradient pass, of a prepared scene: the time a sample, without the
preparation (a fit prepares its scenes once).

    python benchmarks/time_per_sample.py [SCENE ...] [--spp 16] [--threads 1] [--reps 2] [--grad]
    python benchmarks/time_per_sample.py [SCENE ...] --ranges 256,144 [--spp 16] [--reps 5]

SCENE is a scene file or a name: `swatch` (benchmarks/standard_swatch.toml) or a shipped target's name (its
front view, e.g. brown_wavy). Each pass is run once at 1 spp first (compilation, caches), then --reps times; the
line gives the least and the median CPU seconds (time.process_time, all threads) and wall seconds, and µs of
CPU a sample (pixels × spp). On a shared machine compare CPU seconds, and runs of two versions alternated
(docs/benchmarks.md, issue 45).

With --ranges, the forward pass is instead launched one range of pixels at a time (ranges of each given size, in
order), each range's thread CPU time taken (the least of --reps), and the pool's schedule on 2 threads computed
from them (`parallel.launch_ranges` hands the ranges out in order as threads free up): the wall time two threads
would take without other jobs, which a loaded machine cannot show directly.
"""

from __future__ import annotations

import argparse
import heapq
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


def range_costs(prepared, spp: int, size: int, reps: int) -> list:
    """Thread CPU seconds of the forward kernel over each range of `size` pixels, in order (the least of reps)."""
    import warp as wp

    from warp_hair.model.jacobian import CoefficientDerivatives
    from warp_hair.renderer.render import pixel_kernel

    n = prepared.resolution[0] * prepared.resolution[1]
    image, stderr = wp.zeros(n, dtype=wp.vec3), wp.zeros(n, dtype=wp.vec3)
    every = wp.zeros(0, dtype=wp.int32)
    wp.load_module(pixel_kernel.module, device="cpu")
    costs = []
    for first in range(0, n, size):
        inputs = [prepared.data, CoefficientDerivatives(), spp, 5, image, stderr, None, every, first]
        best = float("inf")
        for _ in range(reps):
            start = time.thread_time()
            wp.launch(pixel_kernel, dim=min(size, n - first), inputs=inputs)
            best = min(best, time.thread_time() - start)
        costs.append(best)
    return costs


def makespan(costs: list, threads: int = 2) -> float:
    """When the last range ends, ranges taken in order by whichever thread is free first."""
    free = [0.0] * threads
    for cost in costs:
        heapq.heappush(free, heapq.heappop(free) + cost)
    return max(free)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=["swatch", "brown_wavy"])
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--grad", action="store_true", help="time render_jacobian too")
    parser.add_argument("--ranges", help="comma-separated range sizes: the 2-thread schedule of each (docstring)")
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
        if args.ranges:
            for size in (int(s) for s in args.ranges.split(",")):
                costs = range_costs(prepared, args.spp, size, args.reps)
                total, span = sum(costs), makespan(costs)
                print(
                    f"{name} {args.spp} spp, ranges of {size}: {len(costs)} ranges, CPU {1e3 * total:.1f} ms, on 2 "
                    f"threads {1e3 * span:.1f} ms ({total / 2 / span:.2f} of ideal; load {os.getloadavg()[0]:.2f})",
                    flush=True,
                )
            continue
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
