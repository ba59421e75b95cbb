"""Profile: one render call of a fit at its working point, split into what is fixed per call and what scales with
the samples (issue 45, item 1).

    python benchmarks/fit_render_split.py [--targets brown_wavy,cycles_brown_wavy,chestnut_straight]
                                          [--spps 1,4,16] [--repeat 5] [--threads 2] [--realisations 3]
                                          [--fits black_straight,cycles_brown_wavy:random]

A fit renders each image of its target once or twice an iteration, always on a scene prepared once
(`warp_hair.prepare`), with the hair swapped in (`scene_with_controls` → `PreparedScene.with_hair`): in its Adam
steps as a pair of gradient passes at spp/8 … spp/2 (`render_torch_pair`), in its Gauss–Newton linearisations as
two gradient passes at 4 × spp (`linearize`, `render_jacobian`), in its report as forward renders (`render`).
For each target's front image (48×48, 64×64, 128×128 by default) and both passes, this times:

1. The whole call (`render(prepared.with_hair(hair), spp)` or `render_jacobian(...)`) at each of --spps, the best
   of --repeat rounds (each round calls every spp in turn); a least-squares line through them, time = fixed +
   spp × per sample: its intercept is what a call costs whatever its samples.
2. The call's steps apart, as `render.launch_pixels` takes them: `with_hair` (the hair's coefficients and its
   variation, host), the coefficient derivatives (gradient pass, host), the output buffers (`wp.zeros`, the
   pixel-index array), the launch itself with no samples (the same kernel over the same pixel ranges with spp = 0:
   the thread pool, `wp.load_module`, one `wp.launch` a range, each pixel's stream set up and its outputs
   written) and the read-back to NumPy. Their sum is the fixed part measured directly, beside the intercept.
3. The fit's own call, `render_torch_pair` with its backward pass (two gradient passes and the contraction of
   each image's adjoint with the other's Jacobian), against two `render_jacobian` calls: the torch front's share.
4. With `realisations = "random"` (optimize/realisations.py): drawing a realisation, `realisation(scene, k)` (the
   recipe's generator run with another seed; the scene built from it, with the interpenetration check every new
   assembly gets), and preparing it (`prepare`: the tubes, the BVH, lights and camera), --realisations of them,
   step by step, against a gradient call. The fit keeps each realisation it prepared (a pool of POOL for its
   pairs, DEFAULT_SAMPLES more for the realisation term), per image, so these are paid once per realisation and
   image, not per call; the last column is what they add to a fit that draws them all.
5. With --fits, whole fits with the default settings (a shipped target, `NAME:random` over random realisations):
   the fit's wall time, its render calls (`launch_pixels`: how many, and the time inside them), the kernels'
   launches within them (`launch_ranges`), the realisations drawn and scenes prepared, and the rest: the host's
   work around the renders (losses and their torch graph, Adam, the gains, the Gauss–Newton linear algebra, the
   report and its uncertainty).

Wall seconds are the best of --repeat (the fixed costs include waiting on threads, which CPU time does not
show); CPU seconds (all threads) beside them. On a shared machine the wall times are inflated by other jobs.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from functools import partial
from pathlib import Path

import numpy as np
import warp as wp

from warp_hair.cli import exit_on_interrupt
from warp_hair.geometry.interpenetration import InterpenetrationWarning
from warp_hair.model.jacobian import CoefficientDerivatives, coefficient_derivatives, value_jacobian_mat
from warp_hair.parallel import default_threads, launch_ranges
from warp_hair.realisation import realisation
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import pixel_jacobian_kernel, pixel_kernel, render, tile_pixels
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
TARGETS = HERE.parent / "targets"


def best(fn, repeat) -> tuple:
    """(best wall seconds, best CPU seconds) of `repeat` calls of fn, after one untimed call."""
    return rounds([fn], repeat)[0]


def rounds(fns, repeat) -> list:
    """[(best wall seconds, best CPU seconds)] of each of fns, called in turn `repeat` times after one untimed call
    each: alternating spreads a shared machine's changing load over all of them alike."""
    for fn in fns:
        fn()
    walls, cpus = np.full((repeat, len(fns)), np.inf), np.full((repeat, len(fns)), np.inf)
    for r in range(repeat):
        for k, fn in enumerate(fns):
            wall, cpu = time.perf_counter(), time.process_time()
            fn()
            walls[r, k] = time.perf_counter() - wall
            cpus[r, k] = time.process_time() - cpu
    return list(zip(walls.min(axis=0), cpus.min(axis=0)))


def other_hair(prepared):
    """A look near the scene's own, as a fit's next iterate: a new HairParams each call, as the fit makes."""
    hair = prepared.scene.hair
    return hair.replace(beta_m=hair.beta_m * 1.01)


def call(prepared, differentiable, spp, threads):
    """The fit's call: the hair swapped in, one pass rendered and read back."""
    scene = prepared.with_hair(other_hair(prepared))
    if differentiable:
        return render_jacobian(scene, spp=spp, seed=1, threads=threads)
    return render(scene, spp=spp, seed=1, threads=threads)


def steps(prepared, differentiable, threads, repeat) -> dict:
    """{step: (wall, CPU)} of the fixed steps of `launch_pixels` apart (module docstring, 2)."""
    hair = other_hair(prepared)
    width, height = prepared.resolution
    n = width * height
    # The gradient pass's look also makes each strand's derivatives (`gradient_data`), as launch_pixels asks.
    out = {
        "with_hair": best(
            lambda: prepared.with_hair(hair).gradient_data() if differentiable else prepared.with_hair(hair), repeat
        )
    }
    if differentiable:
        out["coefficient derivatives"] = best(lambda: coefficient_derivatives(hair), repeat)
        kernel, derivs = pixel_jacobian_kernel, coefficient_derivatives(hair)
    else:
        kernel, derivs = pixel_kernel, CoefficientDerivatives()

    def buffers():
        arrays = [wp.zeros(n, dtype=wp.vec3), wp.zeros(n, dtype=wp.vec3), wp.array(np.zeros(0, np.int32))]
        if differentiable:
            arrays.append(wp.zeros(n, dtype=value_jacobian_mat))
        return arrays

    out["output buffers"] = best(buffers, repeat)
    image, stderr, indices, *rest = buffers()
    jacobian = rest[0] if rest else None
    data = prepared.gradient_data() if differentiable else prepared.data
    inputs = [data, derivs, 0, 1, image, stderr, jacobian, indices]
    # spp = 0: the same kernel over the same ranges, no path traced; tile_pixels at the fit's spp.
    chunk = tile_pixels(16, n, max(1, min(threads or default_threads(), n)))
    out["launch, 0 samples"] = best(lambda: launch_ranges(kernel, n, inputs, threads=threads, chunk=chunk), repeat)

    def read_back():
        image.numpy().reshape(height, width, 3)
        stderr.numpy().reshape(height, width, 3)
        if jacobian is not None:
            jacobian.numpy().reshape(height, width, 3, -1)

    out["read back"] = best(read_back, repeat)
    return out


def line(spps, seconds) -> tuple:
    """(intercept, slope) of the least-squares line time = intercept + spp × slope."""
    slope, intercept = np.polyfit(np.asarray(spps, float), np.asarray(seconds, float), 1)
    return intercept, slope


def split_tables(targets, spps, threads, repeat) -> dict:
    """Parts 1 and 2 of the module docstring, one row per image and pass in each table; returns {(image,
    differentiable): the call's wall seconds at each spp}."""
    calls, rows_call, rows_steps = {}, [], []
    for name, prepared in targets.items():
        width, height = prepared.resolution
        for differentiable in (False, True):
            label = f"| {name} {width}×{height} | {'gradient' if differentiable else 'forward'} | "
            timed = rounds([partial(call, prepared, differentiable, s, threads) for s in spps], repeat)
            walls, cpus = [w for w, _ in timed], [c for _, c in timed]
            calls[name, differentiable] = walls
            (wall_fixed, wall_slope), (cpu_fixed, cpu_slope) = line(spps, walls), line(spps, cpus)
            rows_call.append(
                label
                + " | ".join(f"{w * 1e3:.1f}" for w in walls)
                + " | "
                + " | ".join(f"{c * 1e3:.1f}" for c in cpus)
                + f" | {wall_fixed * 1e3:.1f} | {wall_slope * 1e3:.2f} | {cpu_fixed * 1e3:.1f} | "
                f"{cpu_slope * 1e3:.2f} |"
            )
            parts = steps(prepared, differentiable, threads, repeat)
            fixed = sum(wall for wall, _ in parts.values())
            ms = {k: f"{v[0] * 1e3:.2f}" for k, v in parts.items()}
            launch = parts["launch, 0 samples"]
            rows_steps.append(
                label + f"{ms['with_hair']} | {ms.get('coefficient derivatives', '–')} | {ms['output buffers']} | "
                f"{launch[0] * 1e3:.2f} / {launch[1] * 1e3:.2f} | {ms['read back']} | {fixed * 1e3:.2f} | "
                + " / ".join(f"{fixed / w:.1%}" for w in walls)
                + " |"
            )
    spp_columns = " | ".join(f"{s} spp" for s in spps)
    aligned = " | ".join("---:" for _ in spps)
    print(
        f"\n## One call (ms, best of {repeat} alternated rounds; {threads} threads)\n\n"
        f"| image | pass | wall: {spp_columns} | CPU: {spp_columns} | line (wall): fixed | per sample | "
        f"line (CPU): fixed | per sample |\n| --- | --- | {aligned} | {aligned} | ---: | ---: | ---: | ---: |"
    )
    print("\n".join(rows_call))
    print(
        f"\n## The call's fixed steps apart (wall ms, best of {repeat})\n\n| image | pass | with_hair | "
        "coefficient derivatives | output buffers | launch with 0 samples (wall / CPU) | read back | sum | "
        f"share of the call at {' / '.join(str(s) for s in spps)} spp |\n"
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
    )
    print("\n".join(rows_steps))
    return calls


def two_passes(prepared, spp, threads):
    for _ in range(2):
        call(prepared, True, spp, threads)


def pair(prepared, spp, threads):
    """The fit's Adam call on one image: a pair of gradient passes as torch images, a loss, its backward pass."""
    import torch

    from warp_hair.torch import render_torch_pair

    control = torch.tensor(float(prepared.scene.hair.beta_m) * 1.01, dtype=torch.float64, requires_grad=True)
    images = render_torch_pair(prepared, {"beta_m": control}, spp=spp, seed=1, threads=threads)
    images.square().sum().backward()


def torch_table(targets, spps, threads, repeat) -> None:
    """Part 3: the fit's pair call against two gradient passes."""
    print(
        f"\n## The fit's Adam call: render_torch_pair + backward against two render_jacobian (wall ms, best of "
        f"{repeat} alternated rounds)\n\n| image | spp a render | two render_jacobian | render_torch_pair + backward | "
        "the torch front |\n| --- | ---: | ---: | ---: | ---: |"
    )
    for name, prepared in targets.items():
        width, height = prepared.resolution
        for spp in spps:
            (a, _), (b, _) = rounds(
                [partial(two_passes, prepared, spp, threads), partial(pair, prepared, spp, threads)], repeat
            )
            print(f"| {name} {width}×{height} | {spp} | {a * 1e3:.1f} | {b * 1e3:.1f} | {(b - a) * 1e3:+.1f} |")


def realisation_steps(scene, k) -> dict:
    """{step: wall seconds} of drawing realisation k of `scene` and preparing it: the recipe's generator alone, the
    interpenetration check every new assembly gets (scene.check_scene), the rest of `realisation` (the draw, the
    scene's tables, the other checks), and `prepare` split as profile_render.preparation splits it."""
    from profile_render import preparation

    from warp_hair.geometry.interpenetration import interpenetration
    from warp_hair.realisation import realisation_draw
    from warp_hair.scene import GENERATORS

    arguments = {**scene.source["fibers"], **realisation_draw(scene, k)}
    generator = GENERATORS[arguments.pop("generator")]
    start = time.perf_counter()
    fibers = generator(**arguments)
    out = {"generator": time.perf_counter() - start}
    start = time.perf_counter()
    interpenetration(fibers)
    out["interpenetration check"] = time.perf_counter() - start
    start = time.perf_counter()
    other = realisation(scene, k)  # the same strands again, with the check (a new assembly, so not cached)
    whole = time.perf_counter() - start
    out["rest of realisation()"] = whole - out["generator"] - out["interpenetration check"]
    rows = {step: wall for step, wall, _cpu in preparation(other)}
    out["prepare: BVH build"] = rows["BVH build"]
    out["prepare: the rest"] = rows["whole prepare()"] - rows["BVH build"]
    return out


def realisation_table(scenes, targets, calls, spps, count) -> None:
    """Part 4: a realisation's generator run and preparation, against the gradient calls that use it."""
    from optimize.realisations import DEFAULT_SAMPLES, POOL

    rows = []
    for name, scene in scenes.items():
        realisation_steps(scene, count + 1)  # untimed: the first loads the check's and the build's Warp modules
        runs = [realisation_steps(scene, k) for k in range(1, count + 1)]
        mean = {step: float(np.mean([r[step] for r in runs])) for step in runs[0]}
        total = sum(mean.values())
        images = len(list((TARGETS / name).glob("scene_*.toml")))
        width, height = targets[name].resolution
        segments = targets[name].scene.fibers.num_segments
        rows.append(
            f"| {name} {width}×{height} | {segments} | "
            + " | ".join(f"{v * 1e3:.1f}" for v in mean.values())
            + f" | {total * 1e3:.1f} | "
            + " / ".join(f"{total / c:.1f}" for c in calls[name, True])
            # The images share a realisation's strands and BVH (realisation_views, prepare_views): all but the
            # first prepare only the rest.
            + f" | {(total + (images - 1) * mean['prepare: the rest']) * (POOL + DEFAULT_SAMPLES):.2f} |"
        )
    print(
        f"\n## Random realisations: what drawing and preparing one costs (wall ms, the mean of {count})\n\n"
        "| image | segments | "
        + " | ".join(mean)
        + " | sum | the sum in gradient calls at "
        + " / ".join(str(s) for s in spps)
        + f" spp | per fit ({POOL} + {DEFAULT_SAMPLES} realisations, their images sharing the strands), s |\n| --- | "
        + " | ".join("---:" for _ in range(len(mean) + 4))
        + " |"
    )
    print("\n".join(rows))


class Stopwatch:
    """Wraps module attributes (functions) so that each call's wall time is added to one account."""

    def __init__(self):
        self.seconds, self.calls, self._saved = 0.0, 0, []

    def wrap(self, module, name):
        inner = getattr(module, name)

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.calls += 1

        self._saved.append((module, name, inner))
        setattr(module, name, timed)

    def restore(self):
        for module, name, inner in reversed(self._saved):
            setattr(module, name, inner)


def fit_table(fits, threads) -> None:
    """Part 5: whole fits, their wall time split into the render calls (and the kernels' launches within them),
    drawing and preparing scenes, and the rest: the host's work around the renders."""
    from importlib import import_module

    from optimize import fit, load_target
    from optimize.target import SHIPPED_TARGETS

    # By import_module: the package `optimize` exports functions under some of its modules' names (fit).
    fit_module, linearize, realisations, report, arrangement = (
        import_module(f"optimize.{name}") for name in ("fit", "linearize", "realisations", "report", "arrangement")
    )
    render_module, torch_module = import_module("warp_hair.renderer.render"), import_module("warp_hair.torch")

    print(
        f"\n## Whole fits ({threads} threads; wall s)\n\n| fit | wall | render calls | in the calls | of which the "
        "kernels' launches | realisations drawn and scenes prepared | the rest (host: losses, torch, Adam, gains, "
        "linear algebra, report) |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: |"
    )
    for spec in fits:
        name, _, mode = spec.partition(":")
        calls, kernels, scenes = Stopwatch(), Stopwatch(), Stopwatch()
        calls.wrap(render_module, "launch_pixels")
        calls.wrap(torch_module, "launch_pixels")
        kernels.wrap(render_module, "launch_ranges")
        for module in (fit_module, linearize, report):
            scenes.wrap(module, "prepare")
        for module in (realisations, arrangement):  # a realisation's views drawn and prepared together
            scenes.wrap(module, "realisation_views")
            scenes.wrap(module, "prepare_views")
        try:
            target = load_target(SHIPPED_TARGETS / name)
            start = time.perf_counter()
            fit(target, progress=False, threads=threads, **({"realisations": mode} if mode else {}))
            wall = time.perf_counter() - start
        finally:
            for watch in (calls, kernels, scenes):
                watch.restore()
        rest = wall - calls.seconds - scenes.seconds
        print(
            f"| {spec} | {wall:.1f} | {calls.calls} | {calls.seconds:.1f} | {kernels.seconds:.1f} | "
            f"{scenes.seconds:.1f} | {rest:.1f} ({rest / wall:.0%}) |"
        )


def names(text: str) -> list:
    values = [v for v in text.split(",") if v]
    missing = [v for v in values if not (TARGETS / v / "scene_front.toml").is_file()]
    if missing or not values:
        raise argparse.ArgumentTypeError(f"--targets: no targets/NAME/scene_front.toml for {missing or text!r}")
    return values


def spp_list(text: str) -> list:
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--spps takes comma-separated integers, got {text!r}") from None
    if len(values) < 2 or min(values) < 1:
        raise argparse.ArgumentTypeError(f"--spps needs two or more integers of at least 1, got {text!r}")
    return values


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--targets", type=names, default=["brown_wavy", "cycles_brown_wavy", "chestnut_straight"])
    parser.add_argument("--spps", type=spp_list, default=[1, 4, 16])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--realisations", type=int, default=3, help="realisations drawn per image for part 4")
    parser.add_argument("--skip-torch", action="store_true", help="leave out part 3")
    parser.add_argument(
        "--fits",
        default="",
        help="part 5: comma-separated shipped targets to fit whole with default settings, NAME or NAME:random "
        "(e.g. black_straight,cycles_brown_wavy:random); none by default",
    )
    args = parser.parse_args(argv)
    if args.repeat < 1 or args.threads < 1 or args.realisations < 1:
        parser.error("--repeat, --threads and --realisations must be at least 1")
    # The targets' swatches are known to interpenetrate; the check's time is measured (part 4), its message is not news.
    warnings.filterwarnings("ignore", category=InterpenetrationWarning)
    wp.init()
    one, five, fifteen = os.getloadavg()
    print(f"threads {args.threads}; load average {one:.2f}, {five:.2f}, {fifteen:.2f} ({os.cpu_count()} cores)")
    scenes = {name: load_scene(TARGETS / name / "scene_front.toml") for name in args.targets}
    targets = {name: prepare(scene) for name, scene in scenes.items()}
    calls = split_tables(targets, args.spps, args.threads, args.repeat)
    if not args.skip_torch:
        torch_table(targets, args.spps, args.threads, args.repeat)
    realisation_table(scenes, targets, calls, args.spps, args.realisations)
    if args.fits:
        fit_table([f for f in args.fits.split(",") if f], args.threads)
    one, five, fifteen = os.getloadavg()
    print(f"\nend: load average {one:.2f}, {five:.2f}, {fifteen:.2f}")


if __name__ == "__main__":
    exit_on_interrupt(main)
