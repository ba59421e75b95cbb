"""Benchmark: the whole `warp-hair fit` command's wall time in two versions of the code, alternated (issue 45's
goal 2: the fits in half the time).

    python benchmarks/fit_wall_time.py [--base 12242ec] [--head HEAD] [--rounds 2] [--threads N]
                                       [--fit "NAME [FIT OPTIONS]" ...] [--out DIR]

Each version is checked out as a detached `git worktree` in a temporary folder (removed at the end) and run as a
user runs it, `warp-hair fit NAME -o OUT [FIT OPTIONS]`, with loading, pictures and plots, in a new process whose
PYTHONPATH is that worktree (the working directory elsewhere, so that this checkout's packages are not imported).
One warm-up fit of each version first (Warp compiles a version's kernels once), then --rounds rounds, each running
every fit in the base version and then in the head one: on a machine whose load drifts, alternating keeps both
sides under the same drift. Default fits: the Quick start's (black_straight), a photo-like target
(photo_brown_straight_png) and a fit over random realisations (cycles_brown_wavy --realisations random).

Prints a Markdown table: each fit's wall seconds per round on both sides, how many times faster the head is (the
ratio of the means), the Gauss–Newton steps, the fit's own seconds (params.json `seconds`: without loading and
pictures) and the largest |error| / σ where the target has a truth. Fits are deterministic for a seed, so each
side's results are the same every round; a result that differs between the sides is a change of the fit, not of
its speed. Compare runs taken in one session on one machine (docs/benchmarks.md, "The goals at the close").
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from ray_steps import worktree  # a detached `git worktree` of a commit, as ray_steps.py times its versions
from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent
DEFAULT_FITS = ("black_straight", "photo_brown_straight_png", "cycles_brown_wavy --realisations random")
RUN_FIT = "import sys; from optimize.cli import main; sys.exit(main())"


def git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], check=True, capture_output=True, text=True).stdout.strip()


def load_average() -> str:
    load = os.getloadavg()
    return f"load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}"


def run_fit(code: Path, fit: str, out: Path, threads: int | None, workdir: Path) -> dict:
    """One `warp-hair fit` of `code`'s version: its wall seconds and what params.json says of it."""
    name, *options = shlex.split(fit)
    command = [sys.executable, "-c", RUN_FIT, "fit", name, "-o", str(out), *options]
    if threads is not None:
        command += ["--threads", str(threads)]
    env = {**os.environ, "PYTHONPATH": str(code)}
    start = time.perf_counter()
    done = subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode not in (0, 3):  # 3: the fit ran and said it failed; anything else is this benchmark's failure
        raise SystemExit(
            f"fit_wall_time: `{' '.join(command[3:])}` in {code} exited {done.returncode}:\n{done.stderr[-2000:]}"
        )
    params = json.loads((out / "params.json").read_text())
    return {"wall": wall, "failed": done.returncode == 3 or bool(params.get("failed")), **summary(params)}


def summary(params: dict) -> dict:
    """Steps, the fit's own seconds and the largest |error| / σ (None without a truth) from a params.json."""
    worst = None
    errors, sigmas = params.get("error") or {}, params.get("uncertainty") or {}
    ratios = [
        np.abs(np.atleast_1d(errors[name])) / np.atleast_1d(sigmas[name])
        for name in errors
        if name in sigmas and sigmas[name] is not None
    ]
    if ratios:
        worst = float(np.max(np.concatenate(ratios)))
    return {"steps": len(params.get("gauss_newton_steps") or []), "seconds": params.get("seconds"), "worst": worst}


def table(fits, base: str, head: str, results: dict) -> str:
    lines = [
        f"| fit | {base[:7]}: wall s | {head[:7]}: wall s | faster | steps | the fit's own s | largest abs(error)/σ |",
        "| --- | --- | --- | ---: | --- | --- | --- |",
    ]
    for fit in fits:
        b, h = results[(base, fit)], results[(head, fit)]
        walls = [", ".join(f"{r['wall']:.1f}" for r in side) for side in (b, h)]
        ratio = np.mean([r["wall"] for r in b]) / np.mean([r["wall"] for r in h])
        steps = f"{b[-1]['steps']} → {h[-1]['steps']}"
        own = f"{np.mean([r['seconds'] for r in b]):.1f} → {np.mean([r['seconds'] for r in h]):.1f}"
        worst = " → ".join("–" if s[-1]["worst"] is None else f"{s[-1]['worst']:.2f}" for s in (b, h))
        failed = " (failed)" if any(r["failed"] for r in b + h) else ""
        lines.append(f"| `{fit}`{failed} | {walls[0]} | {walls[1]} | {ratio:.2f}× | {steps} | {own} | {worst} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="12242ec", help="the version to compare against (default: before issue 45)")
    parser.add_argument("--head", default="HEAD", help="the version measured (default: HEAD, committed code only)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--threads", type=int, default=None, help="passed to each fit (default: all cores)")
    parser.add_argument("--fit", action="append", help='"NAME [FIT OPTIONS]"; repeat for more (default: three fits)')
    parser.add_argument("--out", type=Path, default=None, help="keep each fit's output here (default: discarded)")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    fits = tuple(args.fit or DEFAULT_FITS)
    try:
        base, head = (
            git("rev-parse", "--verify", f"{args.base}^{{commit}}"),
            git("rev-parse", "--verify", f"{args.head}^{{commit}}"),
        )
    except subprocess.CalledProcessError as error:
        parser.error(f"not a commit of this repository: {error.stderr.strip()}")
    print(
        f"fit wall time, {base[:7]} against {head[:7]}: {len(fits)} fits, {args.rounds} rounds; "
        f"{load_average()} ({os.cpu_count()} cores)"
    )
    with tempfile.TemporaryDirectory(prefix="fit_wall_time_") as tmp:
        folder = Path(tmp)
        out = args.out or folder / "out"
        codes = {}
        try:
            for rev in (base, head):
                codes[rev] = worktree(rev, folder)
            results = {(rev, fit): [] for rev in (base, head) for fit in fits}
            runs = [(rev, fits[0], "warm") for rev in (base, head)]
            runs += [(rev, fit, str(k)) for k in range(1, args.rounds + 1) for rev in (base, head) for fit in fits]
            for rev, fit, round_ in tqdm(runs, desc="fits", unit="fit"):
                target = out / f"{rev[:7]}_{shlex.split(fit)[0]}_{round_}"
                record = run_fit(codes[rev], fit, target, args.threads, folder)
                if round_ != "warm":
                    results[(rev, fit)].append(record)
        finally:
            for path in codes.values():
                git("worktree", "remove", "--force", str(path))
    print(table(fits, base, head, results))
    print(f"end: {load_average()}")


if __name__ == "__main__":
    main()
