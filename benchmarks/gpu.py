"""Benchmark: the renderer on a GPU against the CPU (and Mitsuba 3's cuda_ad_rgb where installed), on the
standard swatch, in one call:

    python benchmarks/gpu.py [--spp 64] [--repeat 3] [--target blonde_straight] [--iters 10] [--threads N]

Per device, after a warm-up call that compiles and loads the kernels (not timed): a forward render at spp
(`render`), a gradient pass at spp (`render_jacobian`: the image and its per-pixel Jacobian), the fit's paired
evaluation (`render_torch_pair` at spp/2 per render and its backward pass, the controls as tensors on that
device) and a short fit of a shipped target (`optimize.fit`, `iters` Adam iterations, no Gauss-Newton steps,
no uncertainties; its final evaluation included). Each timing is the fastest of `repeat` runs, in wall-clock
seconds; a GPU timing ends when the result is on the host (or, for the torch pair, at torch.cuda.synchronize()).
Mitsuba renders the same scene with its stock hair BSDF (`mitsuba_peer.mitsuba_scene`), forward only. The GPU
image is also compared with the CPU's: the same kernel and random streams give the same image up to float
rounding (tests/test_device.py derives the tolerance), so the share of values within it is printed as a check.

The BVH build (`bvh.build_bvh`, the passes over the primitives on the device, the levels' bookkeeping on the
host) is timed apart on the segment boxes of `scaling.py`'s swatches of 10⁴ to 10⁶ segments (`--build`), with
whether both devices build the same tree.

On a machine without a CUDA device it says why and exits 0.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import warp as wp

from optimize import fit, load_target
from optimize.target import SHIPPED_TARGETS
from warp_hair.cli import exit_on_interrupt
from warp_hair.devices import why_no_cuda
from warp_hair.parallel import default_threads
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene
from warp_hair.torch import render_torch_pair

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from mitsuba_peer import mitsuba_scene  # noqa: E402  (the same scene translation)

SCENE = HERE / "standard_swatch.toml"
RTOL = 1e-4  # tests/test_device.py: how far a GPU render may be from the CPU's, path by path


def best_of(repeat: int, run) -> tuple:
    """(fastest wall seconds, the last run's result) of `repeat` calls of run(), after one untimed warm-up."""
    result = run()
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - start)
    return best, result


def torch_pair(prepared, spp: int, device: str):
    """The fit's paired evaluation: two renders at spp/2 and the backward pass of their squared error."""
    on = torch.device(wp.device_to_torch(device))
    controls = {name: torch.tensor(0.3, device=on, requires_grad=True) for name in ("beta_m", "beta_n")}
    pair = render_torch_pair(prepared, controls, spp=max(1, spp // 2), seed=3)
    (0.5 * ((pair - 0.05) ** 2).sum()).backward()
    if on.type == "cuda":
        torch.cuda.synchronize(on)
    return {name: float(t.grad) for name, t in controls.items()}


def time_device(device: str, args) -> dict:
    scene = load_scene(SCENE)
    prepared = prepare(scene, device)
    threads = args.threads if device == "cpu" else None
    timings = {}
    timings["forward"], image = best_of(args.repeat, lambda: render(prepared, spp=args.spp, seed=1, threads=threads))
    timings["gradient"], _ = best_of(
        args.repeat, lambda: render_jacobian(prepared, spp=args.spp, seed=2, threads=threads)
    )
    timings["fit pair"], _ = best_of(args.repeat, lambda: torch_pair(prepared, args.spp, device))
    target = load_target(SHIPPED_TARGETS / args.target)
    start = time.perf_counter()
    fit(target, iters=args.iters, refine=0, uncertainty=False, threads=threads, device=device, progress=False)
    timings["short fit"] = time.perf_counter() - start  # once: its kernels are loaded by now
    return {"timings": timings, "image": image}


def time_builds(sizes, threads: int | None, repeat: int) -> None:
    """The BVH build on each device over the tube boxes of 10 segments a strand (the 10⁶ case is issue 24's
    10⁵-strand groom), and whether the GPU's tree is the CPU's."""
    from scaling import draped_swatch

    from warp_hair.geometry.bvh import TRAVERSAL_COST, build_bvh
    from warp_hair.geometry.intersect import BVH_WIDTH
    from warp_hair.geometry.tubes import MAX_LEAF, segment_boxes, segment_frames

    print("\n| BVH build | CPU s | GPU s | GPU speed-up | same tree |\n|---|---:|---:|---:|---|")
    for m in sizes:
        p0, p1, r0, r1, strand, _ = draped_swatch(m, 10).fibers.segments()
        lowers, uppers = segment_boxes(segment_frames(p0, p1, r0, r1, strand))
        trees, seconds = {}, {}
        for device in ("cpu", "cuda"):

            def build(device=device, lowers=lowers, uppers=uppers):
                return build_bvh(
                    lowers,
                    uppers,
                    max_leaf=MAX_LEAF,
                    width=BVH_WIDTH,
                    traversal_cost=TRAVERSAL_COST,
                    threads=threads,
                    device=device,
                )

            seconds[device], trees[device] = best_of(repeat, build)
        a, b = trees["cpu"], trees["cuda"]
        same = all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("order", "lo", "hi", "child"))
        print(
            f"| {len(lowers)} segments | {seconds['cpu']:.3f} | {seconds['cuda']:.3f} | "
            f"{seconds['cpu'] / seconds['cuda']:.1f}x | {'yes' if same else 'no'} |",
            flush=True,
        )


def time_mitsuba(spp: int, repeat: int) -> tuple:
    """(seconds, image) of Mitsuba's cuda_ad_rgb forward render, or (None, the reason).

    In a child process: Mitsuba aborts the whole process on some errors (a missing data file, no OptiX), which
    must not lose the timings above it."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "mitsuba.npz"
        child = subprocess.run(
            [sys.executable, __file__, "--mitsuba-child", str(out), "--spp", str(spp), "--repeat", str(repeat)],
            capture_output=True,
            text=True,
        )
        if child.returncode != 0 or not out.exists():
            reason = (child.stderr or child.stdout).strip().splitlines()[-1:] or [f"exit status {child.returncode}"]
            return None, f"Mitsuba's cuda_ad_rgb did not run: {reason[0]}"
        saved = np.load(out)
        return float(saved["seconds"]), saved["image"]


def mitsuba_child(out: Path, spp: int, repeat: int) -> None:
    import mitsuba as mi

    mi.set_variant("cuda_ad_rgb")
    scene_mi = mitsuba_scene(mi, load_scene(SCENE), spp)

    def run():
        return np.array(mi.render(scene_mi, spp=spp, seed=1), dtype=np.float32)  # waits for the lazy image

    seconds, image = best_of(repeat, run)
    np.savez(out, seconds=seconds, image=image)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--target", default="blonde_straight", help="the shipped target of the short fit")
    parser.add_argument("--iters", type=int, default=10, help="Adam iterations of the short fit")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")
    parser.add_argument(
        "--build", type=int, nargs="*", default=[10_000, 100_000, 1_000_000], help="segments of the BVH builds timed"
    )
    parser.add_argument("--mitsuba-child", type=Path, help=argparse.SUPPRESS)  # time_mitsuba's own process
    args = parser.parse_args(argv)
    if args.mitsuba_child:
        mitsuba_child(args.mitsuba_child, args.spp, args.repeat)
        return
    if wp.get_cuda_device_count() == 0:
        print(f"no CUDA device: {why_no_cuda()}. This benchmark compares a GPU with the CPU; nothing to do.")
        return
    gpu_name = wp.get_device("cuda").name
    print(f"standard swatch 256x256, {args.spp} spp; CPU: {args.threads or default_threads()} threads; GPU: {gpu_name}")
    cpu = time_device("cpu", args)
    gpu = time_device("cuda", args)
    print("\n| pass | CPU s | GPU s | GPU speed-up |\n|---|---:|---:|---:|")
    for name, seconds in cpu["timings"].items():
        ours = gpu["timings"][name]
        print(f"| {name} | {seconds:.3f} | {ours:.3f} | {seconds / ours:.1f}x |")
    a, b = gpu["image"], cpu["image"]
    close = np.isclose(a, b, rtol=RTOL, atol=RTOL * np.abs(b).max())
    print(
        f"\nGPU image against the CPU's: {close.mean():.2%} of the values within {RTOL:g} relative; means "
        f"{a.mean():.6f} and {b.mean():.6f}; largest difference {np.abs(a - b).max():.3g}",
        flush=True,
    )
    time_builds(args.build, args.threads, args.repeat)
    mitsuba_seconds, mitsuba = time_mitsuba(args.spp, args.repeat)
    if mitsuba_seconds is None:
        print(mitsuba)
    else:
        print(
            f"Mitsuba 3 cuda_ad_rgb forward: {mitsuba_seconds:.3f} s, ours on the GPU "
            f"{gpu['timings']['forward'] / mitsuba_seconds:.2f}x its time; image means (its stock hair BSDF; the "
            f"swatch's strands interpenetrate) {mitsuba.mean():.6f} against our {a.mean():.6f}"
        )


if __name__ == "__main__":
    exit_on_interrupt(main)
