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

Without an address (`--address`, else the RAY_ADDRESS that `ray job submit` sets) it starts a Ray instance on
this machine (all its cores, no dashboard) and stops it at the end; with one it joins that cluster (`ray start
--head` there first); a Ray already initialised in this process (a test's, a notebook's) is used as it is.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import warp_hair

from . import store
from .jobs import PROJECT_ERRORS, load_inputs

POLL_SECONDS = 0.5


@dataclass
class Outcome:
    """What a run did: job names by what became of them this time."""

    done: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # finished by an earlier run
    interrupted: bool = False


def run_batch(manifest, address: str | None = None, cpus: int | None = None, progress: bool = True) -> Outcome:
    """Run `manifest` (a manifest.Manifest); see the module docstring. `cpus`: the local instance's CPUs
    (default all cores); ignored when joining a cluster."""
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
    started = False
    pending = {}
    try:
        if todo:
            started = connect(address, cpus)
            pending = _submit(manifest, todo, outcome, bar)
        while pending:
            ready = _wait(list(pending))
            for ref in ready:
                job, submitted = pending.pop(ref)
                _collect(manifest, job, ref, submitted, outcome)
                bar.update()
                if job.kind == "render":
                    _assemble_render(manifest, outcome, job.group)
        for group in manifest.groups():  # a rerun may find every part of a render finished
            _assemble_render(manifest, outcome, group)
    except KeyboardInterrupt:
        outcome.interrupted = True
        _cancel(pending)
    finally:
        bar.close()
        if started:
            import ray

            ray.shutdown()
        from .report import write_report
        from .summary import write_summary

        write_summary(manifest)
        write_report(manifest)
    if outcome.interrupted:
        raise KeyboardInterrupt
    return outcome


def connect(address: str | None, cpus: int | None) -> bool:
    """Join or start Ray; True when this call started it (and so should stop it)."""
    try:
        import ray
    except ImportError:
        raise ValueError(
            "warp-hair batch needs Ray: pip install -e \".[cluster]\" (or pip install 'ray>=2.60')"
        ) from None
    if ray.is_initialized():
        return False
    # Under `ray job submit`, or wherever a cluster is named in the environment, join it as Ray's own tools do.
    address = address or os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address, log_to_driver=True)
    else:
        ray.init(num_cpus=cpus or len(os.sched_getaffinity(0)), include_dashboard=False, log_to_driver=True)
    return True


def _submit(manifest, todo, outcome, bar) -> dict:
    import ray

    task = ray.remote(_task)
    payloads = {}
    pending = {}
    for job in todo:
        if job.group not in payloads:
            try:
                payloads[job.group] = ray.put(load_inputs(job))
            except PROJECT_ERRORS as error:
                payloads[job.group] = str(error)
        if isinstance(payloads[job.group], str):
            store.write_failed(manifest.output, job.name, job.key, payloads[job.group])
            outcome.failed.append(job.name)
            bar.update()
            continue
        ref = task.options(
            num_cpus=manifest.cpus_per_job, max_retries=manifest.retries, name=f"warp-hair {job.kind} {job.name}"
        ).remote(job, payloads[job.group], warp_hair.__version__)
        pending[ref] = (job, time.time())
    return pending


def _task(job, payload, version: str) -> dict:
    """The Ray task: the job with as many threads as Ray gave it CPUs."""
    import ray

    from .jobs import execute

    threads = max(1, int(ray.get_runtime_context().get_assigned_resources().get("CPU", 1)))
    start = time.time()
    result = execute(job, payload, threads, version)
    result.update(
        started=start,
        seconds=time.time() - start,
        threads=threads,
        pid=os.getpid(),
        node=ray.get_runtime_context().get_node_id(),
    )
    return result


def _wait(refs) -> list:
    import ray

    ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
    return ready


def _collect(manifest, job, ref, submitted: float, outcome) -> None:
    import ray
    from ray.exceptions import RayError, RayTaskError

    try:
        result = ray.get(ref)
    except RayTaskError as error:  # a bug: the task raised something other than a project error
        cause = error.cause if getattr(error, "cause", None) is not None else error
        _failed(manifest, job, f"internal error: {type(cause).__name__}: {cause}", outcome)
        return
    except RayError as error:  # the worker or its node died more often than the retries allow, or the like
        _failed(manifest, job, f"{type(error).__name__}: {str(error).splitlines()[0]}", outcome)
        return
    record = {key: result[key] for key in ("seconds", "threads", "pid", "node")}
    record["queued"] = round(result["started"] - submitted, 3)
    if "error" in result:
        _failed(manifest, job, result["error"], outcome, files=result.get("files"), **record)
        return
    store.write_done(manifest.output, job.name, job.key, result["files"], kind=job.kind, group=job.group, **record)
    outcome.done.append(job.name)


def _failed(manifest, job, error: str, outcome, **record) -> None:
    store.write_failed(manifest.output, job.name, job.key, error, kind=job.kind, group=job.group, **record)
    outcome.failed.append(job.name)


def _assemble_render(manifest, outcome, group: str) -> None:
    """Put the render `group` together once all its parts are finished (once: a rerun finds it done)."""
    jobs = manifest.groups()[group]
    job = jobs[0]
    if job.kind != "render" or store.finished(manifest.output, group, job.key):
        return
    if not all(store.finished(manifest.output, part.name, part.key) for part in jobs):
        return
    try:
        files = _assembled(manifest, jobs)
    except PROJECT_ERRORS as error:
        _failed(manifest, job, str(error), outcome)
        return
    seconds = sum(store.read_status(manifest.output, part.name).get("seconds", 0.0) for part in jobs)
    store.write_done(
        manifest.output,
        group,
        job.key,
        files,
        kind="render",
        group=group,
        seconds=seconds,
        parts=[part.name for part in jobs],
    )


def _assembled(manifest, jobs) -> dict:
    import numpy as np

    from warp_hair.io import write_exr, write_png
    from warp_hair.renderer.render import render_metadata
    from warp_hair.scene import load_scene

    from .jobs import render_sampling
    from .split import assemble

    job = jobs[0]
    scene = load_scene(job.spec["scene"])
    pieces = []
    for part in jobs:
        with np.load(store.job_dir(manifest.output, part.name) / "part.npz") as data:
            pieces.append((data["pixels"], data["image"], data["stderr"]))
    image, stderr = assemble(scene.camera.resolution, pieces)
    spp, seed = render_sampling(job, scene)
    files = {}
    with tempfile.TemporaryDirectory() as folder:
        write_exr(Path(folder) / "image.exr", image, render_metadata(scene, spp, seed))
        write_exr(Path(folder) / "stderr.exr", stderr)
        write_png(Path(folder) / "preview.png", image, exposure=job.spec.get("exposure", 1.0))
        for path in Path(folder).iterdir():
            files[path.name] = path.read_bytes()
    return files


def _cancel(pending: dict) -> None:
    if not pending:
        return
    import ray

    for ref in pending:
        ray.cancel(ref, force=True)
