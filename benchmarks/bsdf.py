"""Throughput of the hair BSDF on the CPU: one importance sample plus its evaluation, in millions per second.

Two views of the same work, each on one core and on all cores:
  batch API  `bsdf.sample` then `bsdf.eval` on the sampled directions, NumPy in and out (validation,
             float64 → float32 conversion and the allocations included);
  kernels    the batch API's own sample kernel (lobe_setup, hair_sample, hair_value_pdf at the sample) per item
             on pre-allocated Warp arrays, spread over the cores by `launch_ranges`.
Inputs: wo uniform on the sphere, h uniform in [−1, 1], u uniform in [0, 1)³; a typical brown material.

`--parts` times the renderer's BSDF calls apart instead, on one core, in nanoseconds a call: `lobe_setup` (once a
path vertex), `hair_sample_incident`, `hair_value_pdf_at` the sample (from the angles it was built from) and
`hair_value_pdf` toward another direction (the light's, whose angles it recovers); a vertex of a path does one of
each, which the last line adds up. Each part is the difference of two kernels that differ by that call only.

    python benchmarks/bsdf.py [--n N] [--repeat R] [--parts]
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np
import warp as wp

import warp_hair
from warp_hair import HairParams, bsdf
from warp_hair.cli import exit_on_interrupt
from warp_hair.model.bsdf import sample_kernel
from warp_hair.model.hair_bsdf import (
    HairCoefficients,
    LobeSetup,
    hair_coefficients,
    hair_sample_incident,
    hair_value_pdf,
    hair_value_pdf_at,
    lobe_setup,
)
from warp_hair.parallel import default_threads, launch_ranges

MATERIAL = HairParams(albedo=(0.6, 0.4, 0.2), beta_m=0.3, beta_n=0.3)


def random_inputs(n: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    r = np.sqrt(1.0 - z * z)
    wo = np.stack([z, r * np.cos(phi), r * np.sin(phi)], axis=1)
    return wo, rng.uniform(-1.0, 1.0, n), rng.random((n, 3))


def batch_api(wo, h, u, threads: int):
    def run():
        wi, _, _ = bsdf.sample(MATERIAL, wo, h, u, threads=threads)
        bsdf.eval(MATERIAL, wo, wi, h, threads=threads)

    return run


def kernels(wo, h, u, threads: int):
    n = len(h)
    arrays = [
        hair_coefficients(MATERIAL),
        wp.array(wo.astype(np.float32), dtype=wp.vec3),
        wp.array(h.astype(np.float32), dtype=float),
        wp.array(u.astype(np.float32), dtype=wp.vec3),
        wp.empty(n, dtype=wp.vec3),
        wp.empty(n, dtype=wp.vec3),
        wp.empty(n, dtype=float),
    ]

    def run():
        launch_ranges(sample_kernel, n, arrays, threads)

    return run


@wp.func
def _kept(setup: LobeSetup):
    """Some of the setup's results, written out by each part's kernel so that the compiler keeps the setup."""
    return wp.vec3(setup.prob[0], float(setup.phi_center[1]), setup.A[1, 0])


@wp.kernel
def _setup_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    setup = lobe_setup(c, wo[i], h[i])
    out[i] = _kept(setup)


@wp.kernel
def _sample_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    u: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    setup = lobe_setup(c, wo[i], h[i])
    out[i] = hair_sample_incident(setup, u[i]).w + _kept(setup)


@wp.kernel
def _sample_value_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    u: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    setup = lobe_setup(c, wo[i], h[i])
    sample = hair_sample_incident(setup, u[i])
    value, pdf = hair_value_pdf_at(setup, sample)
    out[i] = sample.w + value + wp.vec3(pdf, 0.0, 0.0) + _kept(setup)


@wp.kernel
def _value_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    wi: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    setup = lobe_setup(c, wo[i], h[i])
    value, pdf = hair_value_pdf(setup, wi[i])
    out[i] = value + wp.vec3(pdf, 0.0, 0.0) + _kept(setup)


def parts(wo, h, u, repeat: int) -> dict:
    """Nanoseconds a call on one core: the setup, and what a sample and an evaluation add to it (toward directions
    drawn as wo is)."""
    n = len(h)
    wi, _, _ = random_inputs(n, seed=2)
    c = hair_coefficients(MATERIAL)
    vec = {name: wp.array(x.astype(np.float32), dtype=wp.vec3) for name, x in (("wo", wo), ("wi", wi), ("u", u))}
    h_arr = wp.array(h.astype(np.float32), dtype=float)
    out = wp.empty(n, dtype=wp.vec3)

    def timed(kernel, inputs):
        return best_seconds(lambda: launch_ranges(kernel, n, inputs, 1), repeat) / n * 1e9

    setup = timed(_setup_kernel, [c, vec["wo"], h_arr, out])
    sampled = timed(_sample_kernel, [c, vec["wo"], h_arr, vec["u"], out])
    value_at_sample = timed(_sample_value_kernel, [c, vec["wo"], h_arr, vec["u"], out]) - sampled
    value = timed(_value_kernel, [c, vec["wo"], h_arr, vec["wi"], out]) - setup
    return {
        "lobe_setup": setup,
        "hair_sample_incident": sampled - setup,
        "hair_value_pdf_at the sample": value_at_sample,
        "hair_value_pdf toward another wi": value,
    }


def best_seconds(run, repeat: int) -> float:
    run()  # warm-up: compiles or loads the kernels, touches the memory
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def cpu_name() -> str:
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=2_000_000, help="items per launch (default 2 000 000)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement; the best counts (default 3)")
    parser.add_argument("--parts", action="store_true", help="time the renderer's BSDF calls apart, on one core")
    args = parser.parse_args()
    if args.n < 1 or args.repeat < 1:
        parser.error("--n and --repeat must be at least 1")

    cores = default_threads()
    wo, h, u = random_inputs(args.n)
    print(f"warp-hair {warp_hair.__version__}, Warp {wp.config.version}; CPU: {cpu_name()}, {cores} cores")
    if args.parts:
        ns = parts(wo, h, u, args.repeat)
        print(f"one core, best of {args.repeat} launches of {args.n:,} items; ns a call\n")
        for name, value in ns.items():
            print(f"{name:38}{value:8.0f} ns")
        print(f"{'a path vertex (one of each)':38}{sum(ns.values()):8.0f} ns")
        return
    print(f"sample + eval of {args.n:,} items, best of {args.repeat}; M/s = millions of items per second\n")
    print(f"{'':34}{'1 core':>12}{f'{cores} cores':>12}{'speed-up':>10}")
    for name, make in (("batch API (NumPy in/out)", batch_api), ("kernels (setup+sample+value+pdf)", kernels)):
        rates = [args.n / best_seconds(make(wo, h, u, threads), args.repeat) / 1e6 for threads in (1, cores)]
        print(f"{name:34}{rates[0]:8.2f} M/s{rates[1]:8.2f} M/s{rates[1] / rates[0]:9.2f}×")


if __name__ == "__main__":
    exit_on_interrupt(main)
