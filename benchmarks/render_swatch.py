"""Benchmark: time warp-hair on the standard swatch and, where Mitsuba 3 is installed, render the same scene
with it in the same run and compare speed and images.

    python benchmarks/render_swatch.py [--spp 64] [--threads N] [--repeat 1] [--out DIR] [--no-tilt] [--scene TOML]

Mitsuba is an optional extra (`pip install mitsuba`); without it the comparison is skipped. Its LLVM back end
needs libLLVM: DRJIT_LIBLLVM_PATH is set to the system's libLLVM-19 when unset (it must be set before the
import). Timings are wall-clock seconds on a shared machine: other jobs running at the same time inflate them.

Mitsuba 3.9.1's `linearcurve` builds its shading frame from the normal alone, so on fibers along y the frame's
tangent, which the hair BSDF takes as the root-to-tip direction, points tip-to-root wherever the normal faces
-z. There the cuticle tilt acts the wrong way, which makes the images differ by several percent; --no-tilt
renders both with alpha = 0 to compare everything else. The script probes the frame and says so.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from mitsuba_peer import import_mitsuba, mitsuba_scene, time_mitsuba

from warp_hair.cli import exit_on_interrupt
from warp_hair.io import write_exr, write_png
from warp_hair.parallel import default_threads
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
SCENE = HERE / "standard_swatch.toml"
# Mean radiance differing by more than this (relative, any channel) is reported as a disagreement. At 64 spp
# the noise in the image mean is far below it.
AGREEMENT_TOLERANCE = 0.03
# Side of the pixel blocks compared after averaging: a moved or mirrored image can keep the same mean, and
# block means are free of most of the per-pixel noise.
BLOCK = 16


def time_ours(scene, spp, threads, repeat):
    """(warm-up seconds, best seconds, image). The 1-spp warm-up compiles (or loads) the Warp kernels.
    The timed render includes building the BVH and light tables, as every call to `render` does."""
    start = time.perf_counter()
    render(scene, spp=1, threads=threads)
    warmup = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        image = render(scene, spp=spp, threads=threads)
        best = min(best, time.perf_counter() - start)
    return warmup, best, image


def reversed_tangents(mi, mi_scene, fibers):
    """Fraction of probe hits where Mitsuba's shading frame does not run root to tip along the fiber (the hair
    BSDF's local y, which orients the cuticle tilt). Rays come from 16 directions around the middle of each
    strand's first segment; only hits on that segment count."""
    first = fibers.strand_offsets[:-1]
    p0, p1 = fibers.points[first].astype(np.float64), fibers.points[first + 1].astype(np.float64)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[0, 2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(axis, u)
    angles = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)[:, None, None]
    toward = -(np.cos(angles) * u + np.sin(angles) * v).reshape(-1, 3)  # (16·S, 3)
    origins = np.tile(0.5 * (p0 + p1), (16, 1)) - toward

    def vec(a):
        return mi.Vector3f(*(np.ascontiguousarray(a[:, k], dtype=np.float32) for k in range(3)))

    si = mi_scene.ray_intersect(mi.Ray3f(mi.Point3f(vec(origins)), vec(toward)))
    # Mitsuba numbers the segments of all strands in order; strand k's first one follows k earlier strands.
    target = np.tile(first - np.arange(len(first)), 16)
    on_target = np.asarray(si.is_valid()) & (np.asarray(si.prim_index) == target)
    along = np.sum(np.asarray(si.sh_frame.t).T * np.tile(axis, (16, 1)), axis=1)
    return float(np.mean(along[on_target] < 0.99)) if on_target.any() else float("nan")


def blocks(image):
    h, w = (image.shape[0] // BLOCK) * BLOCK, (image.shape[1] // BLOCK) * BLOCK
    return image[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).mean(axis=(1, 3))


def compare(ours, theirs):
    """Print how far apart the two images are; return whether their means agree within AGREEMENT_TOLERANCE."""
    mean_ours, mean_theirs = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
    relative = mean_ours / mean_theirs - 1.0
    block_rms = np.sqrt(np.mean((blocks(ours) / blocks(theirs) - 1.0) ** 2))
    print(
        f"mean RGB: warp-hair {fmt(mean_ours)}, Mitsuba {fmt(mean_theirs)}; "
        f"relative difference (ours/Mitsuba - 1) {fmt(relative, '+.2%')}"
    )
    print(f"RMS relative difference of {BLOCK}x{BLOCK}-pixel block means: {block_rms:.2%}")
    return bool(np.all(np.abs(relative) <= AGREEMENT_TOLERANCE))


def fmt(values, spec=".4f"):
    return "(" + ", ".join(format(v, spec) for v in values) + ")"


def write_images(out, ours, theirs):
    out.mkdir(parents=True, exist_ok=True)
    write_exr(out / "warp_hair.exr", ours)
    write_png(out / "warp_hair.png", ours)
    if theirs is None:
        return "warp_hair.{exr,png}"
    write_exr(out / "mitsuba.exr", theirs)
    write_png(out / "mitsuba.png", theirs)
    # Third panel: block means of ours − Mitsuba, ×5 about a grey of 0.2 (grey: agreement; lighter: ours
    # brighter; tinted: a colour shift). Block means, because per-pixel differences are mostly noise.
    diff = np.kron(blocks(ours) - blocks(theirs), np.ones((BLOCK, BLOCK, 1)))
    diff = np.pad(diff, ((0, ours.shape[0] - diff.shape[0]), (0, ours.shape[1] - diff.shape[1]), (0, 0)))
    write_png(out / "side_by_side.png", np.concatenate([ours, theirs, 0.2 + 5.0 * diff], axis=1))
    return "warp_hair.{exr,png}, mitsuba.{exr,png}, side_by_side.png (ours | Mitsuba | 5x block difference)"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=None, help="default: every core this process may use")
    parser.add_argument("--repeat", type=int, default=1, help="timed renders per renderer; the best is reported")
    parser.add_argument("--out", type=Path, default=HERE / "out")
    parser.add_argument("--no-tilt", action="store_true", help="render both with cuticle tilt alpha = 0")
    parser.add_argument(
        "--scene", type=Path, default=SCENE, help="another scene (e.g. ../shared/bench/draped_swatch.toml)"
    )
    args = parser.parse_args(argv)
    threads = args.threads or default_threads()

    scene = load_scene(args.scene)
    if args.no_tilt:
        scene.hair = scene.hair.replace(alpha=0.0)
    width, height = scene.camera.resolution
    paths = width * height * args.spp
    print(
        f"{args.scene.name}: {width}x{height}, {args.spp} spp, max depth {scene.render.max_depth}, "
        f"{scene.fibers.num_strands} fibers, alpha {scene.hair.alpha:g} deg"
    )
    print(
        f"machine: {os.cpu_count()} cores; threads used: {threads} (timings are wall-clock; other jobs on the "
        "machine slow them down)"
    )

    warmup, seconds, ours = time_ours(scene, args.spp, threads, args.repeat)
    print(
        f"warp-hair: warm-up (1 spp, kernel compile/load) {warmup:.2f} s; render {seconds:.2f} s "
        f"(best of {args.repeat}) = {paths / seconds / 1e6:.3f} M camera paths/s"
    )

    theirs = None
    mi = import_mitsuba()
    if mi is not None:
        mi_scene = mitsuba_scene(mi, scene, args.spp)
        mi_warmup, mi_seconds, theirs = time_mitsuba(mi, mi_scene, args.spp, scene.render.seed, threads, args.repeat)
        print(
            f"Mitsuba {mi.__version__} ({mi.variant()}, path max_depth {scene.render.max_depth + 1}): warm-up "
            f"(1 spp, JIT compile) {mi_warmup:.2f} s; render {mi_seconds:.2f} s (best of {args.repeat}) = "
            f"{paths / mi_seconds / 1e6:.3f} M camera paths/s"
        )
        print(f"time ratio warp-hair / Mitsuba: {seconds / mi_seconds:.2f}")
        agree = compare(ours, theirs)
        reversed_share = reversed_tangents(mi, mi_scene, scene.fibers)
        print(
            f"Mitsuba's linearcurve shading frame runs tip to root (or off the fiber) on {reversed_share:.0%} "
            "of probe hits" + (": its hair BSDF tilts the cuticle the wrong way there" if reversed_share else "")
        )
        if not agree:
            print(
                f"WARNING: the image means differ by more than {AGREEMENT_TOLERANCE:.0%}."
                + (
                    " The reversed frames can explain it while alpha != 0; --no-tilt compares without tilt."
                    if reversed_share and scene.hair.alpha != 0
                    else ""
                )
            )

    print(f"images in {args.out}: {write_images(args.out, ours, theirs)}")


if __name__ == "__main__":
    exit_on_interrupt(main)
