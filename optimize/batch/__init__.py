"""`warp-hair batch MANIFEST.toml`: fits, renders and calibrations over a Ray cluster, with nothing lost.

    warp-hair batch looks.toml                         # a Ray of its own on this machine's cores
    warp-hair batch looks.toml --address HOST:6379     # join a cluster (`ray start --head` there); same manifest

The manifest (manifest.py) lists the work; each job is one Ray task (runner.py) whose inputs travel through the
object store and whose results come back beside the manifest, in OUT/jobs/<job>/ (store.py), as each finishes.
A rerun skips finished jobs and runs failed or changed ones; a worker that dies costs its job one of the
manifest's retries; Ctrl-C keeps what finished. cluster.py starts or joins Ray, safely: its own Ray listens on
the loopback only, and a cluster must check Ray's auth tokens. A render split into parts (split.py) is bit for
bit the render one machine makes. OUT/summary.csv and summary.json (summary.py) tabulate the batch,
OUT/report.html (report.py) shows it. Ray is an optional dependency: pip install -e ".[cluster]".
"""

from .manifest import Job, Manifest, load_manifest
from .runner import Outcome, run_batch

__all__ = ["Job", "Manifest", "Outcome", "load_manifest", "run_batch"]
