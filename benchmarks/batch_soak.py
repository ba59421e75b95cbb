"""A soak of `warp-hair batch` on this machine's own Ray: workers killed every few seconds, one Ctrl-C and a rerun.

    python benchmarks/batch_soak.py [--fits 20] [--parts 4] [--kill-every 5] [--cpus 2] [--retries 3]

Writes a manifest of FITS short fits (the shipped black_straight and blonde_straight targets, each seed its own
job: 3 Adam iterations at spp 2, no Gauss-Newton step) and one render split into PARTS jobs, in
benchmarks/out/batch_soak/, and runs `warp-hair batch MANIFEST --cpus CPUS` on it as a user does, a process in a
session of its own, while a thread kills a running job's worker (SIGKILL to a process of that session titled
"ray::warp-hair ...", Ray's title for a worker running a task) every KILL_EVERY seconds. Once half the jobs are
done it presses Ctrl-C (SIGINT to the batch's process group, as a terminal sends it), waits for the batch to stop,
and runs the same command again, the killing going on, to the end. Then it checks, and exits with status 1 if any
check fails:

- every job ended done, or failed with its reason (summary.json, status.json);
- nothing lost: each job done before the Ctrl-C was skipped by the rerun, its status.json unchanged byte for byte;
- nothing computed twice: no job's results were written twice (each done status.json written once, by one run);
- the results are the one-by-one results: each done fit's values equal the same fit run alone in this process,
  bit for bit, and the render equals one machine's render of the same scene;
- every retry on record is a kill: no job records more retries than the kills that hit it.

It prints the figures: jobs, kills (and the jobs they hit), retries on record, jobs failed, the seconds from
Ctrl-C to the batch's exit, and each run's wall time. Timings are wall-clock seconds on whatever else the machine
is doing at the time.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import warp as wp

import targets
from optimize import FitSettings, fit, load_target
from optimize.batch import load_manifest, store
from warp_hair.io import read_exr
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
SHORT = {"iters": 3, "spp": 2, "refine": 0}
TARGETS = ("black_straight", "blonde_straight")
SCENE = targets.path("black_straight") / "scene_front.toml"
RENDER_SPP = 2


def _truth(target: str) -> dict:
    """The fitted controls' true values: three iterations find no look from the neutral guess (such a fit says it
    failed, optimize/verdict.py), so the soak's fits start at their truth and end done."""
    truth = json.loads((targets.path(target) / "truth.json").read_text(encoding="utf-8"))
    return {name: truth[name] for name in ("albedo", "beta_m", "beta_n")}


def _truth_table(target: str) -> str:
    return "{ " + ", ".join(f"{name} = {value}" for name, value in _truth(target).items()) + " }"


def write_manifest(folder: Path, fits: int, parts: int, retries: int) -> Path:
    lines = [
        f"[batch]\nretries = {retries}\n",
        "[defaults.fit]\n" + "".join(f"{key} = {value}\n" for key, value in SHORT.items()),
    ]
    for k in range(fits):
        target = TARGETS[k % len(TARGETS)]
        lines.append(
            f'[[fit]]\ntarget = "{target}"\nname = "{target}_{k}"\nseed = {k}\ninit = {_truth_table(target)}\n'
        )
    lines.append(f'[[render]]\nscene = "{SCENE}"\nname = "front"\nspp = {RENDER_SPP}\nsplit = {parts}\n')
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "soak.toml"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


class Killer(threading.Thread):
    """Every `every` seconds, SIGKILL one worker of session `session` that runs a job; records each kill."""

    def __init__(self, every: float, seed: int = 0):
        super().__init__(daemon=True)
        self.every, self.random, self.session = every, random.Random(seed), None
        self.kills, self.stopped = [], threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.every):
            running = [(pid, title) for pid, title in workers(self.session) if title.startswith("ray::warp-hair ")]
            if running:
                pid, title = self.random.choice(running)
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    continue
                self.kills.append((time.time(), pid, title.removeprefix("ray::warp-hair ").split(" ", 1)[1]))


def workers(session) -> list:
    """(pid, title) of the processes of `session` (Ray titles a worker with the task it runs)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
            title = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[3]) == session:
            found.append((int(entry), title))
    return found


def done_jobs(manifest) -> dict:
    """Job name → its status.json's bytes, for the jobs (and put-together renders) done now."""
    out = {}
    for name in [job.name for job in manifest.jobs] + list(manifest.groups()):
        path = store.job_dir(manifest.output, name) / store.STATUS
        try:
            data = path.read_bytes()
        except OSError:
            continue
        if json.loads(data)["status"] == "done":
            out[name] = data
    return out


def batch(manifest_path: Path, cpus: int, killer: Killer, interrupt_after=None) -> dict:
    """One `warp-hair batch` run; with `interrupt_after` (a count of done jobs), Ctrl-C once that many are done."""
    manifest = load_manifest(manifest_path)
    command = [sys.executable, "-m", "optimize.cli", "batch", str(manifest_path), "--cpus", str(cpus)]
    log = open(manifest_path.with_suffix(".log"), "a", encoding="utf-8")
    start = time.time()
    process = subprocess.Popen(command, stdout=log, stderr=log, start_new_session=True)
    killer.session = process.pid
    pressed = None
    while process.poll() is None:
        if interrupt_after is not None and pressed is None and len(done_jobs(manifest)) >= interrupt_after:
            pressed = time.time()
            os.killpg(process.pid, signal.SIGINT)  # as a terminal's Ctrl-C: to the batch's whole process group
        time.sleep(0.2)
    log.close()
    return {
        "returncode": process.returncode,
        "ended": time.time(),
        "wall": time.time() - start,
        "to_exit": None if pressed is None else time.time() - pressed,
        "done": done_jobs(manifest),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fits", type=int, default=20)
    parser.add_argument("--parts", type=int, default=4)
    parser.add_argument("--kill-every", type=float, default=5.0, help="seconds between kills (default 5)")
    parser.add_argument("--cpus", type=int, default=2)
    parser.add_argument("--retries", type=int, default=3)
    args = parser.parse_args(argv)

    folder = HERE / "out" / "batch_soak"
    shutil.rmtree(folder, ignore_errors=True)
    path = write_manifest(folder, args.fits, args.parts, args.retries)
    manifest = load_manifest(path)
    jobs = len(manifest.jobs)
    killer = Killer(args.kill_every)
    start = time.time()
    killer.start()
    first = batch(path, args.cpus, killer, interrupt_after=jobs // 2)
    kills_first = len(killer.kills)
    second = batch(path, args.cpus, killer)
    killer.stopped.set()

    problems = []
    if first["returncode"] != 130:
        problems.append(f"the Ctrl-C'd run exited with {first['returncode']}, not 130")
    if second["returncode"] not in (0, 1):
        problems.append(f"the rerun exited with {second['returncode']}")
    summary = json.loads((manifest.output / "summary.json").read_text(encoding="utf-8"))
    statuses = {job.name: store.read_status(manifest.output, job.name) for job in manifest.jobs}
    for name, status in statuses.items():
        if (
            status is None
            or status["status"] not in ("done", "failed")
            or (status["status"] == "failed" and not status.get("error"))
        ):
            problems.append(f"{name} ended {status and status['status']}, without a reason")
    for row in summary:
        if row["status"] not in ("done", "failed") or (row["status"] == "failed" and not row["error"]):
            problems.append(f"summary: {row['name']} is {row['status']}")
    # Nothing lost, nothing computed twice: what the first run finished, the rerun left as it was.
    for name, data in first["done"].items():
        if second["done"].get(name) != data:
            problems.append(f"{name}, done before the Ctrl-C, was written again by the rerun")
    log = path.with_suffix(".log").read_text(encoding="utf-8")
    # One-by-one results (Warp's module loads and the scenes' warnings are the batch's business, not this).
    wp.config.log_level = wp.LOG_WARNING
    warnings.simplefilter("ignore")
    compared = 0
    for job in manifest.jobs:
        if job.kind != "fit" or statuses[job.name]["status"] != "done":
            continue
        name = Path(job.spec["target"]).name
        settings = FitSettings(**SHORT, seed=job.spec["seed"], init=_truth(name))
        alone = fit(load_target(targets.path(name)), settings, progress=False)
        params = json.loads((store.job_dir(manifest.output, job.name) / "params.json").read_text(encoding="utf-8"))
        if params["fitted"] != alone.values:
            problems.append(f"{job.name}: {params['fitted']} in the batch, {alone.values} alone")
        compared += 1
    render_status = store.read_status(manifest.output, "front")
    if render_status is not None and render_status["status"] == "done":
        scene = load_scene(SCENE)
        image, _ = read_exr(store.job_dir(manifest.output, "front") / "image.exr")
        if not np.array_equal(image, render(scene, spp=RENDER_SPP, seed=scene.render.seed)):
            problems.append("the split render is not one machine's render")
    # Every retry is a kill. A job finished (done or failed) by a run records the kills that hit it in that run:
    # one retry each, less the last one of a job that failed with no retries left; the kills of attempts that the
    # Ctrl-C then stopped are on no record (the rerun starts the job afresh).
    finished_by = dict.fromkeys(statuses, "second")
    finished_by.update(dict.fromkeys(first["done"], "first"))
    retries = {name: (status or {}).get("retries", 0) for name, status in statuses.items()}
    expected, stopped, lines = {}, 0, []
    for when, _, name in killer.kills:
        run = "first" if when < first["ended"] else "second"
        if run == finished_by.get(name, "second"):
            expected[name] = expected.get(name, 0) + 1
        else:
            stopped += 1
        status = statuses.get(name) or {}
        fate = "stopped by the Ctrl-C" if run != finished_by.get(name, "second") else status.get("status", "?")
        lines.append(f"  {when - start:6.1f} s  {name}: {fate} (retries on record {status.get('retries', 0)})")
    for name, status in statuses.items():
        if status and status["status"] == "failed" and expected.get(name):
            expected[name] -= 1
    for name in statuses:
        if retries[name] > expected.get(name, 0):
            problems.append(f"{name} records {retries[name]} retries, {expected.get(name, 0)} kills hit it")
    unrecorded = sum(expected.values()) - sum(retries.values())  # a kill as its task was returning its result

    print("kills (seconds from the start, the job hit, what became of it):\n" + "\n".join(lines))
    failed = {name: s["error"] for name, s in statuses.items() if s and s["status"] == "failed"}
    print(f"jobs: {jobs} ({args.fits} fits, a render in {args.parts} parts), {args.cpus} CPUs, retries {args.retries}")
    print(
        f"kills: {len(killer.kills)}, one every {args.kill_every:g} s ({kills_first} before the Ctrl-C): "
        f"{sum(retries.values())} retries on record over {sum(1 for r in retries.values() if r)} jobs, "
        f"{len(killer.kills) - sum(expected.values()) - stopped} ending a job with no retries left, {stopped} of "
        f"attempts the Ctrl-C then stopped, {unrecorded} of tasks already returning"
    )
    print(f"failed: {len(failed)}" + "".join(f"\n  {name}: {error}" for name, error in failed.items()))
    print(
        f"first run: {first['wall']:.1f} s, {len(first['done'])} done, Ctrl-C to exit {first['to_exit']:.1f} s "
        f"(status {first['returncode']}); rerun: {second['wall']:.1f} s (status {second['returncode']}), "
        f"{len(first['done'])} skipped"
    )
    print(f"fits compared with the same fit alone: {compared}")
    messages = [line for line in re.split(r"[\r\n]", log) if line.strip() and not line.startswith("batch soak.toml")]
    print(f"terminal: {len(messages)} lines besides the progress bar, both runs (in {path.with_suffix('.log')})")
    for problem in problems:
        print(f"PROBLEM: {problem}")
    print("all checks passed" if not problems else f"{len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
