"""Benchmark: the cost of one gradient of an image loss with respect to the hair controls, on the standard swatch,
against a forward render, its peak memory at two path depths, and (where Mitsuba 3 is installed) against
Mitsuba's `prb` differentiating its hair BSDF.

    python benchmarks/render_grad.py [--spp 64] [--threads N] [--memory-spp 8] [--repeat 1]

The loss is 0.5‖image − target‖² with a fixed synthetic target (0.9 × a primal render at spp/8, made before
any timing), so its adjoint is image − target. One gradient evaluation is what an optimiser step pays: a primal
render for the adjoint (seed A) plus `render_grad` (seed B; a different seed keeps the two estimates uncorrelated).
The paired evaluation is what `optimize.fit` pays per image and iteration (`warp_hair.torch.render_torch_pair`):
two independent gradient passes of spp/2 samples, each giving its image and per-pixel Jacobian; each image's
adjoint meets the other pass's Jacobian, so no path is traced twice and the two factors stay independent.
With --repeat N ≥ 2 each run uses other seeds, and the spread of the gradients over the runs is printed, so
that the two estimators' noise can be compared along with their cost.
`render_grad` differentiates every control at once (albedo or sigma_a, beta_m, beta_n, alpha, eta,
r_roughness_scale): there is no cheaper call for fewer controls.

Peak memory is each depth's own subprocess's ru_maxrss (a process's peak never goes down, so two depths in one
process cannot be told apart). It includes the interpreter, Warp and the loaded kernels, the same for both.

Timings are wall-clock seconds on a shared machine: other jobs running at the same time inflate them. Each is
followed by the CPU seconds of this process (all its threads, Mitsuba's included), which sharing the cores with
other jobs inflates less. With --repeat N each of the three timings is taken N times and the fastest run kept,
the one least disturbed by other jobs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from warp_hair.cli import exit_on_interrupt
from warp_hair.parallel import default_threads
from warp_hair.renderer.gradients import contract_crossed, named_gradients, render_grad, render_jacobian
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from mitsuba_peer import import_mitsuba, mitsuba_scene  # noqa: E402  (the same scene translation)

SCENE = HERE / "standard_swatch.toml"
SEED_TARGET, SEED_PRIMAL, SEED_GRAD = 7, 1, 2
MEMORY_DEPTHS = (16, 128)
# Mitsuba hair BSDF parameters differentiated when present and flagged differentiable by mi.traverse.
MITSUBA_KEYS = ("longitudinal_roughness", "azimuthal_roughness", "sigma_a.value", "scale_tilt", "eta")


def load(max_depth=None):
    scene = load_scene(SCENE)
    if max_depth is not None:
        scene.render = dataclasses.replace(scene.render, max_depth=max_depth)
    return scene


def target_spp(spp):
    """The target only has to be fixed and plausible, not converged: render it at an eighth of the spp."""
    return max(1, spp // 8)


def synthetic_target(scene, spp, threads):
    """0.9 × a primal render: fixed before timing, so the loss and its adjoint are non-trivial everywhere."""
    return 0.9 * render(scene, spp=target_spp(spp), seed=SEED_TARGET, threads=threads)


def gradient_evaluation(scene, target, spp, threads, run=0):
    """One gradient of 0.5‖image − target‖²: the primal for the adjoint, then the gradient pass (path replay)."""
    image = render(scene, spp=spp, seed=SEED_PRIMAL + 10 * run, threads=threads)
    adjoint = image - target
    grads = render_grad(scene, adjoint, spp=spp, seed=SEED_GRAD + 10 * run, threads=threads)
    return 0.5 * float(np.sum(adjoint.astype(np.float64) ** 2)), grads


def paired_gradient_evaluation(scene, target, spp, threads, run=0):
    """The same loss's gradient from two independent gradient passes of spp/2 each (what `optimize.fit` does):
    each pass gives its image and per-pixel Jacobian, and each image's adjoint meets the other's Jacobian. The
    loss is the mean of the two images' losses; the samples traced are spp per pixel, as in the forward render."""
    passes = [
        render_jacobian(scene, spp=max(1, spp // 2), seed=seed + 10 * run, threads=threads)
        for seed in (SEED_PRIMAL, SEED_GRAD)
    ]
    adjoints = [image.astype(np.float64) - target for _, image, _ in passes]
    g = 0.5 * contract_crossed(adjoints, [jacobian for jacobian, _, _ in passes])
    return 0.25 * float(sum(np.sum(a**2) for a in adjoints)), named_gradients(scene.hair, g)


def timed(fn, *args):
    """(wall-clock seconds, CPU seconds of this process, fn's result)."""
    start, cpu = time.perf_counter(), time.process_time()
    result = fn(*args)
    return time.perf_counter() - start, time.process_time() - cpu, result


def fastest(repeat, fn, *args):
    """`timed(fn, *args)` of the fastest of `repeat` runs."""
    return min((timed(fn, *args) for _ in range(repeat)), key=lambda run: run[0])


def fastest_with_spread(repeat, fn, *args):
    """(wall, CPU, result) of the fastest of `repeat` runs of fn(*args, run), each run with its own seeds, and the
    standard deviation over the runs of each control's gradient (None for a single run)."""
    runs = [timed(fn, *args, k) for k in range(repeat)]
    best = min(runs, key=lambda run: run[0])
    if repeat < 2:
        return best, None
    grads = [run[2][1] for run in runs]
    return best, {
        name: np.std([np.asarray(g[name], dtype=np.float64) for g in grads], axis=0, ddof=1) for name in grads[0]
    }


def format_gradients(grads):
    return ", ".join(
        f"{k} {np.array2string(np.asarray(v), precision=4) if np.ndim(v) else format(float(v), '.4g')}"
        for k, v in grads.items()
    )


def warm_up(scene, threads):
    """Compile (or load) the forward and gradient kernels at 1 spp so no timing includes it."""
    image = render(scene, spp=1, threads=threads)
    render_grad(scene, np.zeros_like(image), spp=1, threads=threads)


def memory_child(depth, spp, threads):
    """Hidden mode: one gradient evaluation at `depth`; print ru_maxrss (MiB) before it and at the end. The
    warm-up (kernel loading, buffers) runs at depth 1 so that `before` holds nothing of the deep paths."""
    warm_up(load(1), threads)
    scene = load(depth)
    target = synthetic_target(scene, 1, threads)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    gradient_evaluation(scene, target, spp, threads)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"depth": depth, "before_mib": before, "peak_mib": peak}))


def peak_memory(depth, spp, threads):
    out = subprocess.run(
        [sys.executable, __file__, "--_memory-child", str(depth), "--spp", str(spp), "--threads", str(threads)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def mitsuba_gradient(mi, scene, spp, threads, repeat):
    """(wall and CPU seconds of one forward+backward pass, loss, gradients, non-differentiable keys) for prb."""
    import drjit as dr

    dr.set_thread_count(threads)
    mi_scene = mitsuba_scene(mi, scene, spp)
    # Same translation as render_swatch.py (mitsuba_peer), but the prb integrator (path replay backpropagation): its
    # backward
    # pass re-traces the paths, so forward+backward is a primal plus an adjoint pass, like ours.
    integrator = mi.load_dict(
        {"type": "prb", "max_depth": scene.render.max_depth + 1, "rr_depth": scene.render.rr_depth}
    )
    params = mi.traverse(mi_scene)
    keys, skipped = [], []
    for name in MITSUBA_KEYS:
        matches = [k for k in params.keys() if k.endswith("bsdf." + name)]
        for k in matches:
            (keys if params.flags(k) & mi.ParamFlags.NonDifferentiable.value == 0 else skipped).append(k)
    target = 0.9 * mi.TensorXf(mi.render(mi_scene, integrator=integrator, spp=target_spp(spp), seed=SEED_TARGET))
    dr.eval(target)

    def step(seed, spp):
        for k in keys:
            dr.enable_grad(params[k])
        params.update()
        image = mi.render(mi_scene, params, integrator=integrator, spp=spp, seed=seed, seed_grad=seed + 1)
        loss = 0.5 * dr.sum(dr.square(image - target), axis=None)
        dr.backward(loss)
        grads = {k: np.array(dr.grad(params[k])) for k in keys}  # forces evaluation of every gradient
        dr.sync_thread()
        return float(np.array(loss).ravel()[0]), grads

    step(100, 1)  # warm-up: traces and JIT-compiles the primal and adjoint kernels (1 spp compiles the same)
    seconds, cpu, (loss, grads) = fastest(repeat, step, SEED_PRIMAL, spp)
    return seconds, cpu, loss, grads, skipped


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=None, help="default: every core this process may use")
    parser.add_argument(
        "--memory-spp",
        type=int,
        default=8,
        help="spp of the memory subprocesses: memory holds per-pixel buffers only, so it does not "
        "grow with spp, and fewer keep the two extra gradient evaluations short",
    )
    parser.add_argument("--repeat", type=int, default=1, help="time each measurement this many times, keep the fastest")
    parser.add_argument("--_memory-child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    threads = args.threads or default_threads()
    if args._memory_child is not None:
        memory_child(args._memory_child, args.spp, threads)
        return

    scene = load()
    width, height = scene.camera.resolution
    print(
        f"{SCENE.name}: {width}x{height}, {args.spp} spp, max depth {scene.render.max_depth}, "
        f"{scene.fibers.num_strands} fibers; loss 0.5|image - 0.9 x primal|^2"
    )
    print(
        f"machine: {os.cpu_count()} cores; threads used: {threads} (wall-clock; other jobs on the machine "
        "slow these down)"
    )

    warm_up(scene, threads)
    target = synthetic_target(scene, args.spp, threads)
    forward, forward_cpu, _ = fastest(args.repeat, render, scene, args.spp, SEED_PRIMAL, threads)
    (gradient, gradient_cpu, (loss, grads)), spread = fastest_with_spread(
        args.repeat, gradient_evaluation, scene, target, args.spp, threads
    )
    (paired, paired_cpu, (paired_loss, paired_grads)), paired_spread = fastest_with_spread(
        args.repeat, paired_gradient_evaluation, scene, target, args.spp, threads
    )
    print(f"warp-hair forward render: {forward:.2f} s (CPU {forward_cpu:.2f} s)")
    print(
        f"warp-hair gradient evaluation (primal + render_grad, all controls at once): {gradient:.2f} s "
        f"= {gradient / forward:.2f} x forward (render_grad alone ~ {gradient / forward - 1:.2f} x); "
        f"CPU {gradient_cpu:.2f} s = {gradient_cpu / forward_cpu:.2f} x"
    )
    print(f"  loss {loss:.4f}; gradients: {format_gradients(grads)}")
    if spread is not None:
        print(f"  std over {args.repeat} runs with other seeds: {format_gradients(spread)}")
    print(
        f"warp-hair paired gradient evaluation (two render_jacobian passes of spp/2, crossed; what the fit uses): "
        f"{paired:.2f} s = {paired / forward:.2f} x forward; CPU {paired_cpu:.2f} s = {paired_cpu / forward_cpu:.2f} x"
    )
    print(f"  loss {paired_loss:.4f}; gradients: {format_gradients(paired_grads)}")
    if paired_spread is not None:
        print(f"  std over {args.repeat} runs with other seeds: {format_gradients(paired_spread)}")

    for depth in MEMORY_DEPTHS:
        m = peak_memory(depth, args.memory_spp, threads)
        print(
            f"peak memory, gradient evaluation at max_depth {depth}: {m['peak_mib']:.0f} MiB "
            f"(subprocess ru_maxrss at {args.memory_spp} spp; {m['before_mib']:.0f} MiB after a depth-1 warm-up, "
            "before the evaluation)"
        )

    mi = import_mitsuba()
    if mi is None:
        return
    try:
        mi_seconds, mi_cpu, mi_loss, mi_grads, skipped = mitsuba_gradient(mi, scene, args.spp, threads, args.repeat)
    except Exception as error:  # report and carry on: the comparison is optional
        print(f"Mitsuba gradient skipped: {type(error).__name__}: {error}")
        return
    print(
        f"Mitsuba {mi.__version__} ({mi.variant()}, prb, max_depth {scene.render.max_depth + 1}) forward+backward: "
        f"{mi_seconds:.2f} s (CPU {mi_cpu:.2f} s); loss {mi_loss:.4f}; differentiated: "
        + ", ".join(f"{k.split('.', 2)[-1]} {np.array2string(v.ravel(), precision=4)}" for k, v in mi_grads.items())
    )
    if skipped:
        print(f"  not differentiable in Mitsuba: {', '.join(skipped)}")
    print(
        f"time ratio warp-hair / Mitsuba (gradient evaluation): {gradient / mi_seconds:.2f} "
        f"(CPU {gradient_cpu / mi_cpu:.2f}); paired: {paired / mi_seconds:.2f} (CPU {paired_cpu / mi_cpu:.2f})"
    )


if __name__ == "__main__":
    exit_on_interrupt(main)
