"""Run a manifest's jobs as Ray tasks and keep every result as it comes.

One Ray task per job, declaring `cpus_per_job` CPUs: Ray starts no more tasks on a node than its CPUs allow, and
each task renders with exactly the threads it declared (read back from Ray, `get_assigned_resources`), so the
cores are never oversubscribed. The driver (this process):

- skips finished jobs (store.py), loads each remaining job's inputs (jobs.py) and puts them in the object store
  once per manifest entry, so the workers need no shared disk;
- submits the tasks with `max_retries` = the manifest's retries: a worker that dies (killed, out of memory)
  costs its job one retry and nothing else; a project error is not retried, it is recorded for that job;
- writes each job's results the moment its task returns (`ray.wait`), and puts a split render together when its
  last part is in;
- on Ctrl-C cancels the running tasks (`ray.cancel(force=True)`: their workers are stopped at once) and keeps
  what finished; the summary and the report are written in every case.

Without an address (`--address`, else the RAY_ADDRESS that `ray job submit` sets) it starts a Ray instance of its
own on this machine (all its cores) and stops it at the end; with one it joins that cluster (`ray start --head`
there first); cluster.py says how, and how safely. A Ray already initialised in this process (a test's, a
notebook's) is used as it is.

The terminal shows the progress bar, each failure as it comes and each distinct warning once: the workers' own
output (Warp's banner and module loads) stays in Ray's worker logs (/tmp/ray/session_latest/logs/worker-*),
and a job's Python warnings come back with its result, into its status.json, the summary and the report. A job
that cost retries records how many (`retries`), as its status, the summary and the report show.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from dataclasses import dataclass, field

import warp_hair

from . import store
from .cluster import connect, ray_messages_off
from .jobs import PROJECT_ERRORS, load_inputs, render_files

POLL_SECONDS = 0.5


@dataclass
class Outcome:
    """What a run did: job names by what became of them this time."""

    done: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # finished by an earlier run
    retried: list = field(default_factory=list)  # done or failed after a worker died under them
    interrupted: bool = False


def run_batch(manifest, address: str | None = None, cpus: int | None = None, progress: bool = True) -> Outcome:
    """Run `manifest` (a manifest.Manifest); see the module docstring. `cpus`: the local instance's CPUs
    (default all cores; an error with an address). `progress`: the progress bar, and each failure and each new
    warning on stderr as it comes."""
    from tqdm import tqdm

    out = manifest.output
    out.mkdir(parents=True, exist_ok=True)
    outcome = Outcome()
    todo = []
    for job in manifest.jobs:
        if store.finished(out, job.name, job.key):
            outcome.skipped.append(job.name)
        else:
            todo.append(job)
    bar = tqdm(
        total=len(manifest.jobs),
        initial=len(outcome.skipped),
        unit="job",
        desc=f"batch {manifest.path.name}",
        disable=not progress,
    )
    news = _News(bar if progress else None)
    started = False
    pending = {}
    quiet = contextlib.ExitStack()
    try:
        if todo:
            started = connect(address, cpus)
            quiet.enter_context(ray_messages_off())
            pending = _submit(manifest, todo, outcome, bar, news)
        while pending:
            _collect_ready(manifest, pending, _wait(list(pending)), outcome, bar, news)
        for group in manifest.groups():  # a rerun may find every part of a render finished
            _assemble_render(manifest, outcome, group, news)
    except KeyboardInterrupt:
        outcome.interrupted = True
        _cancel(manifest, pending, outcome, bar, news)
    finally:
        bar.close()
        if started:
            import ray

            ray.shutdown()
        quiet.close()  # after the shutdown, which may still print what Ray had queued
        from .report import write_report
        from .summary import write_summary

        write_summary(manifest)
        write_report(manifest)
    if outcome.interrupted:
        raise KeyboardInterrupt
    return outcome


class _News:
    """Failures, retries and warnings on stderr as they come, above the progress bar; each distinct warning once
    a run (a hundred fits of one groom would repeat it a hundred times; every job's status keeps its own)."""

    def __init__(self, bar):
        self.bar = bar
        self.seen = set()

    def failed(self, name: str, error: str) -> None:
        self._say(f"{name} failed: {error}")

    def retried(self, name: str, retries: int) -> None:
        self._say(f"{name}: retried {retries} time{'s' if retries > 1 else ''}: its worker died")

    def warned(self, name: str, messages) -> None:
        for message in messages:
            if message not in self.seen:
                self.seen.add(message)
                self._say(f"{name}: warning: {message}")

    def _say(self, text: str) -> None:
        from warp_hair.cli import PROG

        if self.bar is not None:
            self.bar.write(f"{PROG}: {text}", file=sys.stderr)


def _submit(manifest, todo, outcome, bar, news) -> dict:
    """Load each entry's inputs once (their warnings count as its jobs'), put them in the object store, submit
    the jobs; {ref: (job, submitted, the inputs' warnings)} of the submitted ones."""
    import ray

    largest = max((node["Resources"].get("CPU", 0) for node in ray.nodes() if node["Alive"]), default=0)
    if manifest.cpus_per_job > largest:  # Ray would wait for such a node for ever
        raise ValueError(
            f"each job declares {manifest.cpus_per_job} CPUs ([batch] cpus_per_job or --cpus-per-job) and the "
            f"largest node of the Ray cluster has {largest:g}: no job could start"
        )
    task = ray.remote(_task)
    payloads = {}
    pending = {}
    for job in todo:
        if job.group not in payloads:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    payload = ray.put(load_inputs(job))
                except PROJECT_ERRORS as error:
                    payload = str(error)
            payloads[job.group] = payload, _messages(caught)
        payload, loaded = payloads[job.group]
        news.warned(job.name, loaded)
        if isinstance(payload, str):
            _failed(manifest, job, payload, outcome, news, warnings=loaded)
            bar.update()
            continue
        ref = task.options(
            num_cpus=manifest.cpus_per_job, max_retries=manifest.retries, name=f"warp-hair {job.kind} {job.name}"
        ).remote(job, payload, warp_hair.__version__)
        pending[ref] = (job, time.time(), loaded)
    return pending


def _messages(caught) -> list:
    """The distinct messages of caught warnings, in order."""
    return list(dict.fromkeys(str(w.message) for w in caught))


def _task(job, payload, version: str) -> dict:
    """The Ray task: the job with as many threads as Ray gave it CPUs, Warp's banner and module loads left out
    (as the command line leaves them out) and its Python warnings returned with its result."""
    import ray
    import warp as wp

    from .jobs import execute

    threads = max(1, int(ray.get_runtime_context().get_assigned_resources().get("CPU", 1)))
    start = time.time()
    with wp.ScopedLogLevel(max(wp.config.log_level, wp.LOG_WARNING)), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # Python's "once per place" would hide a repeat from a reused worker's job
        result = execute(job, payload, threads, version)
    result.update(
        started=start,
        seconds=time.time() - start,
        threads=threads,
        pid=os.getpid(),
        node=ray.get_runtime_context().get_node_id(),
        retries=_attempt(),
        warnings=_messages(caught),
    )
    return result


def _attempt() -> int:
    """How many times Ray ran this task before (0 on the first try): the retries its job cost. Ray keeps the
    number on the worker (the task's attempt number); it has no public call for it."""
    from ray._private.worker import global_worker

    return int(global_worker.core_worker.get_current_task_attempt_number())


def _wait(refs) -> list:
    import ray

    ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
    return ready


def _collect_ready(manifest, pending: dict, ready, outcome, bar, news) -> None:
    for ref in ready:
        job, submitted, loaded = pending.pop(ref)
        _collect(manifest, job, ref, submitted, loaded, outcome, news)
        bar.update()
        if job.kind == "render":
            _assemble_render(manifest, outcome, job.group, news)


def _collect(manifest, job, ref, submitted: float, loaded: list, outcome, news) -> None:
    import ray
    from ray.exceptions import NodeDiedError, RayError, RayTaskError, WorkerCrashedError

    try:
        result = ray.get(ref)
    except RayTaskError as error:  # a bug: the task raised something other than a project error
        cause = error.cause if getattr(error, "cause", None) is not None else error
        _failed(manifest, job, f"internal error: {type(cause).__name__}: {cause}", outcome, news, warnings=loaded)
        return
    except RayError as error:  # the worker or its node died more often than the retries allow, or the like
        message = f"{type(error).__name__}: {str(error).splitlines()[0]}"
        died = isinstance(error, (WorkerCrashedError, NodeDiedError))  # each death cost a retry
        if died:
            deaths = manifest.retries + 1
            message += f" (its worker died {deaths} time{'s' if deaths > 1 else ''}: [batch] retries = {deaths - 1})"
            if manifest.retries:
                outcome.retried.append(job.name)
        _failed(manifest, job, message, outcome, news, retries=manifest.retries if died else 0, warnings=loaded)
        return
    record = {key: result[key] for key in ("seconds", "threads", "pid", "node", "retries")}
    record["queued"] = round(result["started"] - submitted, 3)
    record["warnings"] = list(dict.fromkeys([*loaded, *result["warnings"]]))
    if record["retries"]:
        outcome.retried.append(job.name)
        news.retried(job.name, record["retries"])
    news.warned(job.name, record["warnings"])
    if "error" in result:
        _failed(manifest, job, result["error"], outcome, news, files=result.get("files"), **record)
        return
    store.write_done(manifest.output, job.name, job.key, result["files"], kind=job.kind, group=job.group, **record)
    outcome.done.append(job.name)


def _failed(manifest, job, error: str, outcome, news, **record) -> None:
    store.write_failed(manifest.output, job.name, job.key, error, kind=job.kind, group=job.group, **record)
    outcome.failed.append(job.name)
    news.failed(job.name, error)


def _assemble_render(manifest, outcome, group: str, news) -> None:
    """Put the split render `group` together once all its parts are finished (once: a rerun finds it done). An
    unsplit render's one job wrote the whole image itself."""
    jobs = manifest.groups()[group]
    job = jobs[0]
    if job.kind != "render" or len(jobs) == 1 or store.finished(manifest.output, group, job.key):
        return
    if not all(store.finished(manifest.output, part.name, part.key) for part in jobs):
        return
    try:
        files = _assembled(manifest, jobs)
    except PROJECT_ERRORS as error:
        _failed(manifest, job, str(error), outcome, news)
        return
    parts = [store.read_status(manifest.output, part.name) for part in jobs]
    store.write_done(
        manifest.output,
        group,
        job.key,
        files,
        kind="render",
        group=group,
        seconds=sum(part.get("seconds", 0.0) for part in parts),
        retries=sum(part.get("retries", 0) for part in parts),
        warnings=list(dict.fromkeys(w for part in parts for w in part.get("warnings", []))),
        parts=[part.name for part in jobs],
    )


def _assembled(manifest, jobs) -> dict:
    import numpy as np

    from warp_hair.scene import load_scene

    from .split import assemble

    scene = load_scene(jobs[0].spec["scene"])
    pieces = []
    for part in jobs:
        with np.load(store.job_dir(manifest.output, part.name) / "part.npz") as data:
            pieces.append((data["pixels"], data["image"], data["stderr"]))
    return render_files(jobs[0], scene, *assemble(scene.camera.resolution, pieces))


def _cancel(manifest, pending: dict, outcome, bar, news) -> None:
    """Keep the results that are in (a task may finish between the last look and Ctrl-C), stop the rest."""
    if not pending:
        return
    import ray

    ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0)
    for ref in pending:
        if ref not in ready:
            ray.cancel(ref, force=True)
    _collect_ready(manifest, pending, ready, outcome, bar, news)
