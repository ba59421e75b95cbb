"""The talk's albedo inversion measured with warp-hair: requested albedo against the albedo the renderer shows.

    python benchmarks/albedo_inversion.py [--spp 256] [--max-depth 1024] [--layers 40] [--threads T]
    python benchmarks/albedo_inversion.py --calibrate [--spp 64] [--layers 40]   # refit P on the same block
    python benchmarks/albedo_inversion.py --mitsuba --cycles   # and the peers' (Mitsuba as shipped and corrected)

The block (`warp_hair.calibrate.block_scene`): 40 layers of straight parallel fibers along y (radius 0.004, the
`swatch` generator's default spacing 0.0122 and layer gap, no two fibers touching), 4 wide in x and 8 long in y,
under a uniform white sky of radiance 1, over a black card, seen head-on by an orthographic camera 0.5 wide at
its centre (32×32 px), so that every pixel is far from the block's sides and ends. Hair: the requested albedo
through the talk's inversion, β_m = 0.3, α = 2°, η = 1.55. The measured albedo is the image mean over the sky
radiance, ± its standard error (from each pixel's sample spread). The Mitsuba 3 figures are issue 12's, on a
block it describes the same way (its fiber spacing and layer gap not given). `--mitsuba` and `--cycles` render
this block in the peers too (the same look as `warp-hair export` writes it; Mitsuba's `linearcurve`, with its
hair sampler as shipped and with the residual lobe corrected, `mitsuba_peer.py`), averaging several seeds.

`--calibrate` runs `warp-hair calibrate`'s fit (warp_hair.calibrate, its default grid of σ_a and β_n) on the
same block instead, and prints its residuals and coefficients next to the talk's.

Depth matters here: light paths in a dense block of light hair are long, so the default is max_depth 1024 with
Russian roulette (from bounce 8); `--max-depth 64` (the renderer's default) shows what the shorter limit loses.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from cycles_peer import import_bpy, render_cycles
from mitsuba_peer import SAMPLERS, import_mitsuba, mitsuba_scene, time_mitsuba
from tqdm import tqdm

from warp_hair.calibrate import (
    BLOCK_MAX_DEPTH,
    block_scene,
    calibrate,
    inversion_toml,
    measure_albedo,
    measured_pixels,
    white_radiance,
)
from warp_hair.geometry.formats import save_fibers
from warp_hair.model.params import TALK_ALBEDO_INVERSION, HairParams
from warp_hair.parallel import default_threads

REQUESTED = (0.2, 0.5, 0.8)
BETA_N = (0.3, 0.9)
MITSUBA = {0.3: (0.22, 0.52, 0.83), 0.9: (0.33, 0.62, 0.87)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--max-depth", type=int, default=BLOCK_MAX_DEPTH)
    parser.add_argument("--layers", type=int, default=40)
    parser.add_argument("--threads", type=int)
    parser.add_argument("--calibrate", action="store_true", help="refit the inversion on the block instead")
    parser.add_argument(
        "--mitsuba",
        action="store_true",
        help="render the block in Mitsuba 3 too, its hair sampler as shipped and corrected",
    )
    parser.add_argument(
        "--mitsuba-seeds",
        type=int,
        default=16,
        help="Mitsuba renders per value, averaged: its block renders are heavy-tailed (default 16)",
    )
    parser.add_argument("--cycles", action="store_true", help="render the block in Blender Cycles too (4 seeds)")
    args = parser.parse_args()
    if args.calibrate:
        run_calibration(args)
        return
    mitsuba = mitsuba_block_renderer(args) if args.mitsuba else None
    cycles = cycles_block_renderer(args) if args.cycles else None
    rows = []
    start_wall, start_cpu = time.perf_counter(), time.process_time()
    with tqdm(total=len(REQUESTED) * len(BETA_N), unit="render") as bar:
        for beta_n in BETA_N:
            for k, albedo in enumerate(REQUESTED):
                scene = block_scene(
                    HairParams(albedo=albedo, beta_n=beta_n), layers=args.layers, max_depth=args.max_depth
                )
                mask = measured_pixels(scene)
                measured, error = measure_albedo(
                    scene, mask, white_radiance(scene), spp=args.spp, seed=k, threads=args.threads
                )
                peers = [] if mitsuba is None else [mitsuba(scene, mask, sampler, k) for sampler in SAMPLERS]
                peers += [] if cycles is None else [cycles(scene, mask, k)]
                rows.append((beta_n, albedo, measured, error, MITSUBA[beta_n][k], mask.mean(), peers))
                bar.update()
    print(
        f"{args.layers} layers, 32x32 px, {args.spp} spp, max_depth {args.max_depth}: "
        f"{time.perf_counter() - start_wall:.0f} s wall, {time.process_time() - start_cpu:.0f} s CPU"
    )
    extra = ["Mitsuba as shipped", "Mitsuba, residual lobe corrected"] if mitsuba is not None else []
    extra += ["Cycles"] if cycles is not None else []
    print("| β_n | requested | warp-hair | Mitsuba 3 (issue 12) |" + "".join(f" {e} |" for e in extra))
    print("|---|---|---|---|" + "---|" * len(extra))
    for beta_n, albedo, measured, error, issue, covered, peers in rows:
        note = "" if covered == 1.0 else f" (only {covered:.0%} of the pixels covered)"
        cells = "".join(f" {mean:.3f} ± {error:.3f} |" for mean, error in peers)
        print(f"| {beta_n} | {albedo} | {measured:.3f} ± {error:.3f}{note} | {issue} |" + cells)


def cycles_block_renderer(args, seeds=4):
    """render(scene, mask, seed) -> (albedo, standard error) Cycles shows on the block over `seeds` renders, or
    exit if bpy is not installed."""
    bpy = import_bpy()
    if bpy is None:
        raise SystemExit(1)

    def render_block(scene, mask, seed):
        threads = args.threads or default_threads()
        return seed_average(
            lambda s: render_cycles(bpy, scene, args.spp, threads=threads, seed=s),
            scene,
            mask,
            range(seed * seeds, (seed + 1) * seeds),
        )

    return render_block


def seed_average(render_seed, scene, mask, seeds):
    """(albedo, standard error) over renders `render_seed(s)` for s in `seeds`: each render's mean over `mask`
    (channels summed) over the white card's, and the spread of those means."""
    white = np.sum(white_radiance(scene))
    means = np.array([render_seed(s).astype(np.float64).sum(axis=-1)[mask].mean() for s in seeds]) / white
    return float(means.mean()), float(means.std(ddof=1) / np.sqrt(len(means)))


def mitsuba_block_renderer(args):
    """render(scene, mask, sampler, seed) -> (albedo, standard error) Mitsuba shows on the block (as
    `measure_albedo`) over --mitsuba-seeds renders, fibers along y as a `linearcurve` (right there:
    docs/MODEL.md), or exit if Mitsuba is not installed. One render's mean is heavy-tailed (a rare long path
    through the light block carries much), so the error comes from the spread of the renders' means."""
    mi = import_mitsuba()
    if mi is None:
        raise SystemExit(1)
    directory = Path(tempfile.mkdtemp())
    files = {}

    def render_block(scene, mask, sampler, seed):
        if scene.fibers.num_strands not in files:
            files[scene.fibers.num_strands] = directory / f"block_{scene.fibers.num_strands}.txt"
            save_fibers(scene.fibers, files[scene.fibers.num_strands])
        mi_scene = mitsuba_scene(
            mi, scene, args.spp, shape="linearcurve", fibers_file=files[scene.fibers.num_strands], sampler=sampler
        )
        threads = args.threads or default_threads()
        return seed_average(
            lambda s: time_mitsuba(mi, mi_scene, args.spp, s, threads, 1)[2],
            scene,
            mask,
            range(seed * args.mitsuba_seeds, (seed + 1) * args.mitsuba_seeds),
        )

    return render_block


def run_calibration(args) -> None:
    scene = block_scene(HairParams(sigma_a=0.1), layers=args.layers, max_depth=args.max_depth)
    start_wall, start_cpu = time.perf_counter(), time.process_time()
    with tqdm(unit="render") as bar:

        def progress(done, total):
            bar.total = total
            bar.update(done - bar.n)

        result = calibrate(scene, spp=args.spp, threads=args.threads, progress=progress)
    print(
        f"{args.layers} layers, 32x32 px, {args.spp} spp, max_depth {args.max_depth}: "
        f"{time.perf_counter() - start_wall:.0f} s wall, {time.process_time() - start_cpu:.0f} s CPU"
    )
    print(result.table())
    print(result.summary())
    print(f"the talk's: {', '.join(f'{p:.6g}' for p in TALK_ALBEDO_INVERSION)}")
    print(inversion_toml(result.coefficients), end="")


if __name__ == "__main__":
    main()
