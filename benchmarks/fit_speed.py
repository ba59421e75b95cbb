"""Benchmark: the wall and CPU time of a short fit of a shipped target, for comparing two versions of the code.

    python benchmarks/fit_speed.py [brown_wavy] [--iters 60] [--refine 2]
    PYTHONPATH=/path/to/other/checkout python benchmarks/fit_speed.py ...   # the same fit with other code

Runs `optimize.fit` from the neutral guess with fewer iterations than the default and no uncertainties, and
prints one JSON line: which `optimize` ran, wall and CPU seconds (time.process_time: all threads), the fitted
values. Fits are deterministic for a seed, so two versions that render the same images fit the same values;
alternate the versions in one session (A, B, A, B) on a shared machine, where the load changes from run to run.
"""

from __future__ import annotations

import argparse
import json
import time

import optimize
from optimize import fit, load_target
from optimize.target import SHIPPED_TARGETS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", nargs="?", default="brown_wavy")
    parser.add_argument("--iters", type=int, default=60)
    parser.add_argument("--refine", type=int, default=2)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    target = load_target(SHIPPED_TARGETS / args.target)
    wall, cpu = time.perf_counter(), time.process_time()
    result = fit(target, progress=False, iters=args.iters, refine=args.refine, uncertainty=False, threads=args.threads)
    print(
        json.dumps(
            {
                "optimize": optimize.__file__,
                "target": args.target,
                "wall": time.perf_counter() - wall,
                "cpu": time.process_time() - cpu,
                "values": result.values,
            }
        )
    )


if __name__ == "__main__":
    main()
