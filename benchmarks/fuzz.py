"""Fuzz the inputs: seeded mutations of the shipped scenes, fiber files, hair controls, targets and photos.

    python benchmarks/fuzz.py [--cases 4000] [--seed 0] [--memory-mib 2048] [--seconds 60] [--jobs 2]
    python benchmarks/fuzz.py --areas "JPEG data" --cases 1000     # how many changed JPEG bytes libjpeg sees

Every case runs in a forked child with an address-space limit (RLIMIT_AS: what the process already maps plus
--memory-mib) and a CPU-time limit, and the parent kills it after a wall-clock limit. Each outcome must be a
project error (ValueError or OSError) whose message names the input (the file, or the table and key), or, for
inputs that load, a finite render (BSDF values for hair controls) that is not black where the mutation cannot
darken the image (hair controls, render settings), or a photo (a damaged one only where it is a JPEG). Prints a
table of cases per area and outcome, and the failing cases; exits 1 if any case failed.

The cases and their checks are tests/helpers/fuzz.py, which tests/test_fuzz.py runs in-process on fewer cases.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from helpers.fuzz import AREAS, PASSING, cases, run_all, table, warm_up


def main() -> None:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=4000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--areas", nargs="+", choices=AREAS, default=AREAS, metavar="AREA", help=f"of {AREAS}")
    parser.add_argument("--memory-mib", type=int, default=2048, help="address space a case may add (MiB)")
    parser.add_argument("--seconds", type=int, default=60, help="CPU seconds a case may take")
    parser.add_argument("--jobs", type=int, default=2, help="cases run at the same time")
    parser.add_argument("--workdir", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "warp-hair-fuzz")
    args = parser.parse_args()
    all_cases = cases(args.seed, args.cases, args.areas)
    warm_up(args.workdir)
    results = []
    start = time.perf_counter()
    with tqdm(total=len(all_cases), unit="case") as bar:
        results = run_all(all_cases, args.workdir, args.memory_mib * 2**20, args.seconds, args.jobs, bar)
    shutil.rmtree(args.workdir, ignore_errors=True)
    print(
        f"\n{len(results)} cases (seed {args.seed}) in {time.perf_counter() - start:.0f} s, "
        f"each in a child limited to +{args.memory_mib} MiB and {args.seconds} CPU s\n"
    )
    print(table(results))
    failures = [(c, r) for c, r in results if r[0] not in PASSING]
    for case, (outcome, detail) in failures[:50]:
        print(f"\nFAIL #{case.index} {case.area} {case.source}: {case.mutation}\n  {outcome}: {detail[:300]}")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    from warp_hair.cli import exit_on_interrupt

    exit_on_interrupt(main)
