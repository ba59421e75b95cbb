"""Instructions per ray of the BVH traversal, by kind of ray: a measure of the traversal that the load of a shared
machine does not change (valgrind's callgrind counts instructions; wall-clock rates need a quiet machine).

    python benchmarks/ray_instructions.py [--scene benchmarks/standard_swatch.toml] [--rays 5000] [--record-spp 1]
    python benchmarks/ray_instructions.py --render [--scene …]
    python benchmarks/ray_instructions.py --time [--scene …] [--rays 400000] [--record-spp 4] [--repeat 3]

The paths of a render of the scene (`profile_render.recorded_rays`: camera rays, a shadow ray per vertex,
BSDF-sampled continuations) are recorded once, a fixed random sample of `--rays` of each kind is kept, and each
kind is traced (`rays.intersect`, shadow rays `rays.occluded`) in a child process under
`valgrind --tool=callgrind`, with instrumentation switched on only around that one launch. The count is that of
the JIT-compiled kernel (callgrind attributes code without symbols to its caller, libffi's call into it): the
traversal, the tube tests, and for closest hits the hit point and shading frame and the writes of the outputs.
The rays do not depend on the BVH (its hits are the same), so the counts compare BVH and traversal designs.
With --render, the count is instead that of a whole render, one thread, of 1024 random pixels of the scene
at 4 spp (everything the process runs inside `render`: traversal, BSDF, sampling, libm), per path.
With --time, the recorded rays are instead timed on the clock, one launch (one core) per kind, the best of
--repeat: µs a ray, the closest hits' shading frame and writes included. Needs a quiet machine, and runs of two
versions alternated to compare them. The counts need valgrind (`apt-get install valgrind`).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
KINDS = ("camera", "continuation", "shadow")
RENDER_PIXELS = 1024
RENDER_SPP = 4


def record(scene_path, out, spp, count, seed=7):
    """Save `count` rays of each kind (a fixed random sample of those of `spp` paths per pixel) to `out`."""
    import warp as wp
    from profile_render import recorded_rays

    from warp_hair.renderer.prepare import prepare
    from warp_hair.scene import load_scene

    wp.init()
    rays = recorded_rays(prepare(load_scene(scene_path)), spp, seed=seed)
    rng = np.random.default_rng(0)
    arrays = {}
    for kind, (o, d) in rays.items():
        pick = np.sort(rng.choice(len(o), size=min(len(o), count), replace=False))
        arrays[f"{kind}_o"], arrays[f"{kind}_d"] = o[pick], d[pick]
    np.savez(out, **arrays)


def _saved_rays(scene_path, rays_file, kinds):
    """(bvh, {kind: (run, origins, directions)}) for the saved rays, each kind's kernel loaded on a few of them."""
    import warp as wp

    from warp_hair.geometry.rays import intersect, occluded
    from warp_hair.renderer.prepare import prepare
    from warp_hair.scene import load_scene

    wp.init()
    bvh = prepare(load_scene(scene_path)).bvh
    saved = np.load(rays_file)
    out = {}
    for kind in kinds:
        o, d = saved[f"{kind}_o"], saved[f"{kind}_d"]
        run = occluded if kind == "shadow" else intersect
        run(bvh, o[:10], d[:10])  # load the kernel outside the count or the timing
        out[kind] = (run, o, d)
    return bvh, out


def trace(scene_path, rays_file, kind):
    """Trace one kind of the saved rays, with callgrind's instrumentation on around the launch only."""
    bvh, rays = _saved_rays(scene_path, rays_file, (kind,))
    run, o, d = rays[kind]
    _instrument("on")
    run(bvh, o, d)
    _instrument("off")


def render_pixels(scene_path, _unused, _kind):
    """Render 1024 random pixels at 4 spp on one thread, with callgrind's instrumentation on around it only."""
    import warp as wp

    from warp_hair.renderer.prepare import prepare
    from warp_hair.renderer.render import render
    from warp_hair.scene import load_scene

    wp.init()
    prepared = prepare(load_scene(scene_path))
    width, height = prepared.resolution
    pixels = np.sort(np.random.default_rng(0).choice(width * height, RENDER_PIXELS, replace=False))
    render(prepared, spp=1, threads=1, pixels=pixels[:4])  # load the kernels outside the count
    _instrument("on")
    render(prepared, spp=RENDER_SPP, seed=1, threads=1, pixels=pixels)
    _instrument("off")


def time_rays(scene_path, rays_file, repeat) -> dict:
    """µs a ray of each kind of the saved rays, one launch on one core, the best of `repeat`."""
    import time

    bvh, rays = _saved_rays(scene_path, rays_file, KINDS)
    out = {}
    for kind, (run, o, d) in rays.items():
        best = np.inf
        for _ in range(repeat):
            start = time.perf_counter()
            run(bvh, o, d)
            best = min(best, time.perf_counter() - start)
        out[kind] = best / len(o) * 1e6
    return out


def _instrument(flag):
    subprocess.run(["callgrind_control", "-i", flag, str(os.getpid())], check=True, capture_output=True)


def kernel_instructions(out_file) -> int:
    """Instructions of the JIT code: callgrind_annotate's line for libffi's caller (it has no symbols)."""
    text = subprocess.run(["callgrind_annotate", out_file], check=True, capture_output=True, text=True).stdout
    for line in text.splitlines():
        if "libffi" in line:
            return int(re.match(r"\s*([\d,]+)", line).group(1).replace(",", ""))
    raise RuntimeError(f"no libffi line in {out_file}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(HERE / "standard_swatch.toml"), help="scene TOML")
    parser.add_argument("--rays", type=int, default=5000, help="rays of each kind (default 5000)")
    parser.add_argument("--record-spp", type=int, default=1)
    parser.add_argument("--render", action="store_true", help="count a whole render's instructions a path instead")
    parser.add_argument("--time", action="store_true", help="time the recorded rays on one core instead")
    parser.add_argument("--repeat", type=int, default=3, help="with --time: the best of this many runs")
    parser.add_argument("--trace", nargs=2, metavar=("RAYS_FILE", "KIND"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    scene = args.scene
    if args.trace:
        (render_pixels if args.render else trace)(scene, *args.trace)
        return
    if args.render:
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "render.callgrind")
            command = [sys.executable, __file__, "--scene", scene, "--render", "--trace", "-", "-"]
            subprocess.run(command, check=True, capture_output=True)
            valgrind = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}"]
            subprocess.run([*valgrind, *command], check=True, capture_output=True)
            text = Path(out).read_text()
            total = next(int(line.split()[1]) for line in text.splitlines() if line.startswith("totals:"))
            per_path = total / (RENDER_PIXELS * RENDER_SPP)
            print(
                f"{scene}: a render of {RENDER_PIXELS} pixels at {RENDER_SPP} spp: {per_path:.0f} instructions a path"
            )
        return
    with tempfile.TemporaryDirectory() as tmp:
        rays_file = os.path.join(tmp, "rays.npz")
        record(scene, rays_file, args.record_spp, args.rays)
        if args.time:
            rates = time_rays(scene, rays_file, args.repeat)
            print(f"{scene}, {args.rays} recorded rays of each kind at most, one core, best of {args.repeat}")
            print("\n| rays | µs a ray |\n|---|---:|\n" + "\n".join(f"| {k} | {v:.3f} |" for k, v in rates.items()))
            return
        print(f"{args.scene}, {args.rays} recorded rays of each kind\n\n| rays | instructions a ray |\n|---|---:|")
        command = [sys.executable, __file__, "--scene", scene, "--trace", rays_file]
        # Compile or load the kernels natively first: under valgrind a compile takes minutes.
        subprocess.run([*command, "camera"], check=True, capture_output=True)
        for kind in KINDS:
            out = os.path.join(tmp, f"{kind}.callgrind")
            valgrind = ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}"]
            subprocess.run([*valgrind, *command, kind], check=True, capture_output=True)
            print(f"| {kind} | {kernel_instructions(out) / args.rays:.0f} |", flush=True)


if __name__ == "__main__":
    main()
