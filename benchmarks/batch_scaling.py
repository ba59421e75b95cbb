"""The acceptance batch on one local Ray worker against two: the speed-up, and where the overhead goes.

    python benchmarks/batch_scaling.py [--workers 1 2] [--short] [--only NAME ...] [--warmup]

Runs benchmarks/acceptance_batch.toml (every shipped target at `warp-hair fit`'s defaults; --short: 12
iterations at spp 8 with 2 Gauss-Newton steps, for a shared machine; --only: a subset) with `warp-hair batch`'s
runner on a local Ray of N CPUs, one CPU (one Warp thread) a job, each N in a fresh results folder under
benchmarks/out/batch_scaling/. Prints per N: Ray's start, the batch's wall time, the sum and mean of the jobs'
own seconds (as each task timed itself, imports and Warp's kernel loading included), and the efficiency: that
sum over N × the wall time (1.0: no time lost to scheduling, transfers, writing results or idle workers).
--warmup also times a fresh process's tiny fit with Warp's kernel cache warm and with an empty one (the
compile a fresh machine pays).
Timings are wall-clock seconds on whatever else the machine is doing at the time.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tomlkit

from optimize.batch import load_manifest, run_batch, store
from optimize.batch.cluster import connect
from warp_hair.cli import exit_on_interrupt

HERE = Path(__file__).resolve().parent
SHORT = {"iters": 12, "spp": 8, "refine": 2}
TINY_FIT = (
    "import targets; from optimize import fit, load_target; "
    "fit(load_target(targets.path('black_straight')), iters=1, spp=1, refine=0, progress=False)"
)


def manifest_copy(folder: Path, short: bool, only) -> Path:
    document = tomlkit.parse((HERE / "acceptance_batch.toml").read_text(encoding="utf-8"))
    if short:
        document["defaults"]["fit"].update(SHORT)
    if only:
        kept = [entry for entry in document["fit"] if entry["target"] in only]
        document["fit"].clear()
        document["fit"].extend(kept)
    document["batch"]["output"] = "results"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "acceptance_batch.toml"
    path.write_text(tomlkit.dumps(document), encoding="utf-8")
    return path


def run(workers: int, short: bool, only) -> dict:
    import ray

    folder = HERE / "out" / "batch_scaling" / f"{workers}_workers"
    shutil.rmtree(folder, ignore_errors=True)
    manifest = load_manifest(manifest_copy(folder, short, only))
    start = time.perf_counter()
    connect(None, workers)  # the batch's own local Ray, as `warp-hair batch --cpus N` starts it
    started = time.perf_counter()
    try:
        outcome = run_batch(manifest, progress=True)
    finally:
        ray.shutdown()
    wall = time.perf_counter() - started
    statuses = [store.read_status(manifest.output, job.name) for job in manifest.jobs]
    seconds = [s["seconds"] for s in statuses]
    return {
        "workers": workers,
        "jobs": len(manifest.jobs),
        "failed": outcome.failed,
        "ray_start": started - start,
        "wall": wall,
        "job_seconds": sum(seconds),
        "efficiency": sum(seconds) / workers / wall,
    }


def warmup() -> dict:
    """Seconds of a fresh process's tiny fit (imports, kernels, one iteration) with the cache warm and cold."""
    out = {}
    for label, cache in (("warm", None), ("cold", tempfile.mkdtemp(prefix="warp-cache-"))):
        env = dict(os.environ, **({"WARP_CACHE_PATH": cache} if cache else {}))
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", TINY_FIT], env=env, check=True, capture_output=True)
        out[label] = time.perf_counter() - start
        if cache:
            out["cache_mb"] = sum(p.stat().st_size for p in Path(cache).rglob("*") if p.is_file()) / 1e6
            shutil.rmtree(cache)
    return out


def table(results) -> str:
    lines = [
        "| workers | jobs | Ray start (s) | wall (s) | jobs' own seconds (sum) | mean job (s) | efficiency |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        lines.append(
            f"| {r['workers']} | {r['jobs']} | {r['ray_start']:.1f} | {r['wall']:.1f} | "
            f"{r['job_seconds']:.1f} | {r['job_seconds'] / r['jobs']:.1f} | {r['efficiency']:.2f} |"
        )
    if len(results) > 1:
        lines.append(
            f"\nspeed-up {results[0]['workers']} -> {results[-1]['workers']} workers: "
            f"{results[0]['wall'] / results[-1]['wall']:.2f}x"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--short", action="store_true", help=f"short fits ({SHORT}) for a shared machine")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="fit only these targets of the batch")
    parser.add_argument(
        "--warmup", action="store_true", help="also time a fresh process with a warm and a cold Warp kernel cache"
    )
    args = parser.parse_args()
    results = [run(n, args.short, args.only) for n in args.workers]
    print(table(results))
    if args.warmup:
        w = warmup()
        print(
            f"fresh process, tiny fit: warm kernel cache {w['warm']:.1f} s, empty cache {w['cold']:.1f} s "
            f"(the compile; {w['cache_mb']:.1f} MB of kernels)"
        )
    (HERE / "out" / "batch_scaling" / "results.json").write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    exit_on_interrupt(main)
