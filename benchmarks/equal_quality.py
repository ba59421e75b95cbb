"""Benchmark: noise per second at equal quality, warp-hair against Mitsuba 3's samplers, in one run (issue 45).

    python benchmarks/equal_quality.py [--spps 4,16,64] [--scenes standard,draped] [--repeat 3] [--threads 2]
                                       [--samplers independent,multijitter,ldsampler] [--ref-spp 1024]
                                       [--draped PATH] [--draped-shape bsplinecurve] [--no-mitsuba] [--cuda]
                                       [--mitsuba-lights uniform,weighted]

For each swatch, renderer and spp it renders the image `--repeat` times, with seeds 0, 1, …, on `--threads`
threads (round by round, each renderer in turn, so that a shared machine's changing load falls on all alike),
and keeps the best wall time (and that render's CPU seconds, all threads of the process) and the mean
of the images' relative MSE (one seed's MSE varies: by up to 15% on the draped swatch at 4 spp).
Each image is compared with that renderer's OWN reference, so that the renderers' small differences (their
curves, Mitsuba's frame on `linearcurve`) do not count, only each one's noise:

    relative MSE = (1/3) Σ_c [ mean_pixels (img_c − ref_c)² − v_c ] / mean_pixels(ref_c)²
    relative RMSE = √(relative MSE);   efficiency = 1 / (relative MSE × wall seconds)

c runs over R, G, B. The error is normalised by each channel's image mean, not pixel by pixel: a pixel-wise
relative error divides by radiances near 0 deep in the swatch, where one lit path makes it heavy-tailed, and a
floor would be an arbitrary constant that decides the figure; the image mean is large and steady, so the
figure is the image's L2 error at its own scale (exposure-free), and for an unbiased estimator with independent
samples MSE × spp is constant, so its efficiency does not depend on spp. Pixels with no noise (the constant
sky) count in the mean for both renderers alike.

The reference is two renders of --ref-spp/2 each with seeds 1001 and 1002 (above the timed seeds: --repeat is
at most 1000), ref = (A + B)/2. It still has noise of its own, which adds to the measured mean square error;
v_c = mean_pixels (A_c − B_c)²/4 estimates it (E[(A − B)²]/4 = Var(ref) for any sampler whose two renders are
independent), and is subtracted, so the figure is each image's own error (at 64 spp the reference's share is
about 6% of the MSE for independent samples). The reference's own relative RMSE is printed too. Mitsuba's
samplers all converge to the same image, so one reference (its `independent` sampler) serves them all.

warp-hair renders the swatch prepared once (`warp_hair.prepare`: the BVH built once, as a fit does and as
Mitsuba's scene is loaded once); Mitsuba 3.9.1 `llvm_ad_rgb` renders the scene as benchmarks/mitsuba_peer.py
builds it (its `hair` BSDF as shipped, the `stock` sampler the speed benchmarks use), both swatches as a
`linearcurve`: the polyline warp-hair renders, as render_swatch.py times it (on the draped swatch its shading
frame is wrong, docs/MODEL.md, which changes its image, not its cost or its noise against its own reference);
`--draped-shape bsplinecurve` renders the draped one as vs_peers.py does for agreement (the cubic curve through
`bspline_control_points`, a costlier intersection and other fibers). Each pixel sampler is timed (`independent`,
`multijitter`, `ldsampler`), each with Mitsuba's own choice of light (uniform over its emitters) and with
the weights warp-hair chooses its lights by (warp_hair.renderer.light_sampler) given to Mitsuba's emitters as their
`sampling_weight`: the light choice is a setting a Mitsuba user can make, so it is compared apart from the rest.
Each renderer is warmed up (kernels compiled or loaded) before it is timed; Dr.Jit
may compile again for a new spp, so --repeat 1 can count a compile in Mitsuba's time (the default 3 keeps the
best).

The swatches: benchmarks/standard_swatch.toml (640 fibers, 256×256, depth 16) and
../shared/bench/draped_swatch.toml (152 draped fibers that do not overlap, 128×128, depth 100; --draped PATH).
References are cached under benchmarks/out/equal_quality/, keyed by the swatch's files, the renderer (warp-hair's
code: the git tree of warp_hair/ and any uncommitted change to it; Mitsuba's version), spp and seed, so a rerun
renders only the timed images. References are rendered on every core (their time is not measured).

With --cuda, the same again on a GPU: warp-hair with device="cuda" against Mitsuba's `cuda_ad_rgb`, against the
same references; without a CUDA device (or Mitsuba's CUDA variant) it says so and skips that part.
Timings are wall-clock on a possibly shared machine: the load average is printed at the start and the end.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from mitsuba_peer import SENSOR_SAMPLERS, bspline_control_points, import_mitsuba, mitsuba_scene

from warp_hair.cli import exit_on_interrupt
from warp_hair.geometry.formats import save_fibers
from warp_hair.parallel import default_threads
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCENES = {
    "standard": HERE / "standard_swatch.toml",
    "draped": ROOT.parent / "shared" / "bench" / "draped_swatch.toml",
}
MITSUBA_SHAPES = ("linearcurve", "bsplinecurve")
# The warm-up's spp: one that every Mitsuba sampler takes as it is (ldsampler rounds 1 up to 4, with a warning).
WARMUP_SPP = 4
REFERENCE_SEEDS = (1001, 1002)
CACHE = HERE / "out" / "equal_quality"
WARP_HAIR = "warp-hair"
LIGHTS_WEIGHTED = ", lights weighted as warp-hair's"
MITSUBA_LIGHTS = {"uniform": False, "weighted": True}


def load_average() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} ({os.cpu_count()} cores)"


def warp_hair_stamp() -> str:
    """What warp-hair's images depend on: the committed tree of warp_hair/ and any uncommitted change to it."""
    from warp_hair import __version__

    def git(*args):
        result = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, check=False)
        return result.stdout if result.returncode == 0 else b""

    tree = git("rev-parse", "HEAD:warp_hair").strip()
    changes = git("diff", "HEAD", "--", "warp_hair")
    return f"{__version__}:{tree.decode()}:{hashlib.sha1(changes).hexdigest() if changes else ''}"


def scene_digest(path: Path, scene) -> str:
    """The swatch's own files: its TOML and its fibers file."""
    digest = hashlib.sha1(path.read_bytes())
    digest.update(Path(scene.source["fibers"]["file"]).read_bytes())
    return digest.hexdigest()


class Renderer:
    """One renderer (and sampler) on one backend: `image(spp, seed, threads)` renders; `key` names its references,
    which `reference_image` (same signature) renders."""

    def __init__(self, name, key, image, reference_image=None):
        self.name, self.key, self.image = name, key, image
        self.reference_image = reference_image or image


def warp_hair_renderer(scene, device, stamp) -> Renderer:
    prepared = prepare(scene, device)

    def image(spp, seed, threads):
        return render(prepared, spp=spp, seed=seed, threads=threads)

    name = WARP_HAIR if device == "cpu" else f"{WARP_HAIR} ({device})"
    return Renderer(name, f"warp-hair:{stamp}", image)


def mitsuba_renderers(mi, scene, shape, fibers_file, samplers, light_weights) -> list:
    """A Renderer per pixel sampler (and per choice of lights in `light_weights`: False, Mitsuba's uniform one;
    True, warp-hair's weights as Mitsuba's `sampling_weight`). Their one reference is the independent sampler's with
    uniform lights: every one converges to the same image, and independent samples make the reference's noise
    estimate (module docstring) plain."""
    import drjit as dr

    def renderer_of(sensor_sampler, weighted=False):
        mi_scene = mitsuba_scene(
            mi,
            scene,
            WARMUP_SPP,
            shape=shape,
            fibers_file=fibers_file,
            sensor_sampler=sensor_sampler,
            light_weights=weighted,
        )

        def image(spp, seed, threads):
            dr.set_thread_count(threads)
            return np.array(mi.render(mi_scene, spp=spp, seed=seed), dtype=np.float32)

        return image

    images = {(sampler, weighted): renderer_of(sampler, weighted) for weighted in light_weights for sampler in samplers}
    reference_image = images.get(("independent", False)) or renderer_of("independent")
    return [
        Renderer(
            f"Mitsuba {mi.__version__} {mi.variant()} {shape}, {sampler}{LIGHTS_WEIGHTED if weighted else ''}",
            f"mitsuba:{mi.__version__}:{shape}:independent",
            image,
            reference_image,
        )
        for (sampler, weighted), image in images.items()
    ]


def timed(renderers, spp, threads, repeat) -> list:
    """[(best wall seconds, CPU seconds of that render, the images)] of each renderer's `repeat` renders at `spp`,
    with seeds 0, 1, …: round by round, each renderer in turn, so that a shared machine's changing load falls on
    them alike. Converting to NumPy inside the timing waits for Mitsuba's lazily evaluated image."""
    best, images = [(np.inf, np.inf)] * len(renderers), [[] for _ in renderers]
    for seed in range(repeat):
        for k, renderer in enumerate(renderers):
            wall, cpu = time.perf_counter(), time.process_time()
            images[k].append(renderer.image(spp, seed, threads))
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            best[k] = min(best[k], (wall, cpu))
    return [(*b, i) for b, i in zip(best, images)]


def reference(renderer, swatch, digest, ref_spp) -> tuple:
    """(A, B): the renderer's two reference halves of ref_spp/2 each, from the cache or rendered on every core."""
    halves = []
    for seed in REFERENCE_SEEDS:
        key = hashlib.sha1(f"{digest}|{renderer.key}|{ref_spp // 2}|{seed}".encode()).hexdigest()[:16]
        path = CACHE / f"{swatch}_{renderer.key.split(':')[0]}_{ref_spp // 2}spp_seed{seed}_{key}.npy"
        if path.is_file():
            halves.append(np.load(path))
            continue
        start = time.perf_counter()
        image = renderer.reference_image(ref_spp // 2, seed, default_threads())
        seconds = time.perf_counter() - start
        print(f"  reference half by {renderer.key.split(':')[0]}, {ref_spp // 2} spp, seed {seed}: {seconds:.1f} s")
        CACHE.mkdir(parents=True, exist_ok=True)
        np.save(path, image)
        halves.append(image)
    return tuple(halves)


def relative_mse(image, halves) -> tuple:
    """(relative MSE of `image`, the reference's own relative MSE): the module docstring's definition."""
    a, b = (np.asarray(h, dtype=np.float64) for h in halves)
    ref = 0.5 * (a + b)
    mean = ref.mean(axis=(0, 1))
    own = ((a - b) ** 2).mean(axis=(0, 1)) / 4.0
    error = ((np.asarray(image, dtype=np.float64) - ref) ** 2).mean(axis=(0, 1))
    return float(np.mean((error - own) / mean**2)), float(np.mean(own / mean**2))


def cuda_available(mi) -> str | None:
    """None when both renderers can run on a GPU here, else why not."""
    import warp as wp

    wp.init()
    if wp.get_cuda_device_count() == 0:
        return "no CUDA device"
    if mi is not None and "cuda_ad_rgb" not in mi.variants():
        return "this Mitsuba has no cuda_ad_rgb variant"
    return None


def backends(args, mi) -> list:
    """[(device, Mitsuba variant or None)] to measure."""
    out = [("cpu", None if mi is None else "llvm_ad_rgb")]
    if args.cuda:
        why_not = cuda_available(mi)
        if why_not:
            print(f"--cuda: skipped, {why_not}.")
        else:
            out.append(("cuda", None if mi is None else "cuda_ad_rgb"))
    return out


def measure(args, mi) -> list:
    """[(swatch, backend, spp, renderer name, wall s, CPU s, relative MSE)], and the references' figures printed."""
    rows = []
    stamp = warp_hair_stamp()
    for device, variant in backends(args, mi):
        if variant is not None:
            mi.set_variant(variant)
        threads = args.threads if device == "cpu" else 1
        for swatch in args.scenes:
            path = args.draped if swatch == "draped" else SCENES[swatch]
            scene = load_scene(path)
            digest = scene_digest(path, scene)
            width, height = scene.camera.resolution
            print(
                f"\n{swatch} swatch ({path}): {width}x{height}, depth {scene.render.max_depth}, "
                f"{scene.fibers.num_strands} fibers; {device}; {load_average()}"
            )
            with tempfile.TemporaryDirectory() as tmp:
                renderers = [warp_hair_renderer(scene, device, stamp)]
                if mi is not None:
                    fibers_file = None
                    shape = args.draped_shape if swatch == "draped" else "linearcurve"
                    if shape == "bsplinecurve":
                        fibers_file = Path(tmp) / "control_points.txt"
                        save_fibers(bspline_control_points(scene.fibers), fibers_file)
                    renderers += mitsuba_renderers(
                        mi, scene, shape, fibers_file, args.samplers, [MITSUBA_LIGHTS[x] for x in args.mitsuba_lights]
                    )
                references = []
                for renderer in renderers:
                    references.append(reference(renderer, swatch, digest, args.ref_spp))
                    own = relative_mse(references[-1][0], references[-1])[1]
                    print(f"  {renderer.name}: reference {args.ref_spp} spp, its own relative RMSE {np.sqrt(own):.4f}")
                for renderer in renderers:
                    renderer.image(WARMUP_SPP, 0, threads)  # kernels compiled or loaded
                for spp in args.spps:
                    for renderer, halves, (wall, cpu, images) in zip(
                        renderers, references, timed(renderers, spp, threads, args.repeat)
                    ):
                        mses = [relative_mse(image, halves)[0] for image in images]
                        mse = float(np.mean(mses))
                        print(
                            f"  {renderer.name}, {spp} spp: {wall:.3f} s ({cpu:.3f} s CPU), relative MSE {mse:.4g} "
                            f"(seeds: {', '.join(f'{m:.4g}' for m in mses)})"
                        )
                        rows.append((swatch, device, spp, renderer.name, wall, cpu, mse))
    return rows


def table(rows, threads) -> str:
    """The markdown table: per swatch, backend and spp, each renderer's figures and its efficiency over warp-hair's
    (by wall time, and by CPU time, steadier on a shared machine)."""
    lines = [
        f"| swatch | spp | renderer | time s (best, {threads} threads) | CPU s | relative RMSE | efficiency 1/s | "
        "against warp-hair | by CPU time |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    groups = {}
    for row in rows:
        groups.setdefault((row[0], row[1], row[2]), []).append(row)
    for (swatch, device, spp), group in groups.items():
        ours = next((r for r in group if r[3].startswith(WARP_HAIR)), None)
        for _swatch, _device, _spp, name, wall, cpu, mse in group:
            rmse = f"{np.sqrt(mse):.3f}" if mse > 0 else "below the reference's noise"
            efficiency = 1.0 / (mse * wall) if mse > 0 else np.inf
            if ours is not None and mse > 0 and ours[6] > 0:
                ratio = f"{ours[6] * ours[4] / (mse * wall):.2f}×"
                cpu_ratio = f"{ours[6] * ours[5] / (mse * cpu):.2f}×"
            else:
                ratio = cpu_ratio = "–"
            label = swatch if device == "cpu" else f"{swatch} ({device})"
            lines.append(
                f"| {label} | {spp} | {name} | {wall:.3f} | {cpu:.3f} | {rmse} | {efficiency:.4g} | {ratio} | "
                f"{cpu_ratio} |"
            )
    return "\n".join(lines)


def spp_list(text: str) -> list:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--spps takes comma-separated integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"--spps must be integers of at least 1, got {text!r}")
    return values


def choices(allowed, option):
    def parse(text):
        values = text.split(",")
        unknown = [v for v in values if v not in allowed]
        if unknown:
            raise argparse.ArgumentTypeError(f"{option}: unknown {unknown}; allowed: {list(allowed)}")
        return values

    return parse


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spps", type=spp_list, default=[4, 16, 64], help="timed spp, comma-separated")
    parser.add_argument("--scenes", type=choices(SCENES, "--scenes"), default=list(SCENES))
    parser.add_argument(
        "--samplers", type=choices(SENSOR_SAMPLERS, "--samplers"), default=list(SENSOR_SAMPLERS), help="Mitsuba's"
    )
    parser.add_argument("--repeat", type=int, default=3, help="timed renders per figure; the best is kept")
    parser.add_argument("--threads", type=int, default=2, help="threads of both renderers' timed renders")
    parser.add_argument("--ref-spp", type=int, default=1024, help="samples per pixel of each reference (even)")
    parser.add_argument("--draped", type=Path, default=SCENES["draped"], help="the draped swatch's TOML")
    parser.add_argument(
        "--draped-shape", choices=MITSUBA_SHAPES, default="linearcurve", help="Mitsuba's curve on the draped swatch"
    )
    parser.add_argument(
        "--mitsuba-lights",
        type=choices(MITSUBA_LIGHTS, "--mitsuba-lights"),
        default=list(MITSUBA_LIGHTS),
        help="how Mitsuba chooses its lights: uniform (its default), weighted (warp-hair's weights as sampling_weight)",
    )
    parser.add_argument("--cuda", action="store_true", help="also warp-hair on a GPU against Mitsuba's cuda_ad_rgb")
    parser.add_argument("--no-mitsuba", action="store_true", help="warp-hair alone")
    args = parser.parse_args(argv)
    if not 1 <= args.repeat <= 1000 or args.threads < 1:
        parser.error("--repeat must be in [1, 1000] (its seeds stay below the references') and --threads at least 1")
    if args.ref_spp < 2 or args.ref_spp % 2:
        parser.error(f"--ref-spp must be an even number of at least 2 (two halves), got {args.ref_spp}")
    if "draped" in args.scenes and not args.draped.is_file():
        parser.error(f"the draped swatch {args.draped} does not exist; pass --draped PATH or --scenes standard")

    mi = None if args.no_mitsuba else import_mitsuba()
    print(f"equal quality, one run: spp {args.spps}, reference {args.ref_spp} spp, best of {args.repeat}")
    print(f"start: {load_average()}")
    rows = measure(args, mi)
    print(f"\nend: {load_average()}\n")
    print(table(rows, args.threads))


if __name__ == "__main__":
    exit_on_interrupt(main)
