"""Where a batch's results live, and what says a job is finished.

    OUT/jobs/<job>/...            the job's files (params.json, convergence.png, ... / part.npz / calibration.*)
    OUT/jobs/<job>/status.json    written last: {"status": "done" | "failed", "key", "seconds", "error", ...}
    OUT/jobs/<render>/image.exr   a render put together from its parts (preview.png beside it)
    OUT/summary.csv, summary.json, report.html

A job is finished when its status.json says "done" with the job's current key (manifest.py): the files it lists
were written before it, so a batch stopped at any moment leaves finished jobs whole and the rest to run again.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

STATUS = "status.json"


def job_dir(out: Path, name: str) -> Path:
    return Path(out) / "jobs" / name


def read_status(out: Path, name: str) -> dict | None:
    try:
        return json.loads((job_dir(out, name) / STATUS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def finished(out: Path, name: str, key: str) -> bool:
    status = read_status(out, name)
    return status is not None and status.get("status") == "done" and status.get("key") == key


def write_done(out: Path, name: str, key: str, files: dict, **record) -> Path:
    """Write the job's files, then its status (each file replaced whole, so a crash never leaves half a file)."""
    folder = job_dir(out, name)
    if folder.exists() and not finished(out, name, key):
        shutil.rmtree(folder)  # a failed or stale earlier run's files
    folder.mkdir(parents=True, exist_ok=True)
    for filename, data in files.items():
        _replace(folder / filename, data)
    _replace(folder / STATUS, _json({"status": "done", "key": key, "files": sorted(files), **record}))
    return folder


def write_failed(out: Path, name: str, key: str, error: str, files: dict | None = None, **record) -> None:
    """A failed job's status, with what it left to look at (a failed fit's params.json and pictures)."""
    folder = job_dir(out, name)
    folder.mkdir(parents=True, exist_ok=True)
    for filename, data in (files or {}).items():
        _replace(folder / filename, data)
    _replace(folder / STATUS, _json({"status": "failed", "key": key, "error": error, **record}))


def _json(data) -> bytes:
    return (json.dumps(data, indent=2) + "\n").encode()


def _replace(path: Path, data: bytes) -> None:
    partial = path.with_name(path.name + ".partial")
    partial.write_bytes(data)
    os.replace(partial, path)
