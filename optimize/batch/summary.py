"""The batch's table: summary.json (one object per manifest entry) and summary.csv (the same, flattened).

Per entry: its name, kind and status (done, failed, or pending: not run yet, or stopped), the seconds its task(s)
ran, the error of a failed one, the retries it cost (reruns after its worker died) and its warnings; for a fit
the fitted controls, their 1σ, the truth and the error where the target has truth.json, the iterations, stop
reason and loss; for a render its spp, seed and parts; for a calibration the fitted coefficients p_0..p_5 and
χ²/dof. RGB controls get a column per channel in the CSV (`albedo.r`, `albedo.r.sigma`, `albedo.r.true`, ...).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from . import store

CHANNELS = ("r", "g", "b")


def rows(manifest) -> list:
    """One dict per manifest entry, from what the batch's folder holds now."""
    table = []
    for group, jobs in manifest.groups().items():
        job = jobs[0]
        row = {"name": group, "kind": job.kind, "status": "pending", "seconds": None, "error": None, "retries": None}
        status = entry_status(manifest, group, jobs)
        if status is not None:
            row.update(status=status["status"], error=status.get("error"), retries=status.get("retries", 0))
            if status["status"] == "done":
                row["seconds"] = round(status.get("seconds", 0.0), 1)
                row.update(_details(job, store.job_dir(manifest.output, group)))
            # The job's Python warnings (a fit's own checks are in its params.json), each once.
            row["warnings"] = list(dict.fromkeys([*row.get("warnings", []), *status.get("warnings", [])]))
        table.append(row)
    return table


def entry_status(manifest, group: str, jobs) -> dict | None:
    """The status of a manifest entry: its job's (a render's: the put-together image's, else its failed parts');
    None while pending. Results of another key (stale) do not count."""
    status = store.read_status(manifest.output, group)
    if status is not None and status.get("key") == jobs[0].key:
        return status
    if jobs[0].kind == "render":
        parts = [store.read_status(manifest.output, part.name) for part in jobs]
        failed = [
            (part, s)
            for part, s in zip(jobs, parts)
            if s is not None and s.get("key") == part.key and s["status"] == "failed"
        ]
        if failed:
            return {
                "status": "failed",
                "error": "; ".join(f"{part.name}: {s['error']}" for part, s in failed),
                "retries": sum(s.get("retries", 0) for _, s in failed),
                "warnings": [w for _, s in failed for w in s.get("warnings", [])],
            }
    return None


def _details(job, folder: Path) -> dict:
    if job.kind == "fit":
        params = json.loads((folder / "params.json").read_text(encoding="utf-8"))
        return {
            "target": Path(job.spec["target"]).name,
            "fitted": params["fitted"],
            "sigma": params.get("uncertainty"),
            "true": params.get("true", {}),
            "error_vs_true": params.get("error", {}),
            "iterations": params["iterations"],
            "stop_reason": params["stop_reason"],
            "loss": params["loss"],
            # The measure of fit (optimize/goodness.py): 1 where the fitted look describes the images to their noise.
            "chi2_per_dof": (params.get("goodness_of_fit") or {}).get("chi2_per_dof"),
            "warnings": params.get("warnings", []),
        }
    if job.kind == "render":
        from warp_hair.io import read_exr

        _, metadata = read_exr(folder / "image.exr")
        record = metadata.get("warp_hair", {})
        return {"spp": record.get("spp"), "seed": record.get("seed"), "parts": job.part[1]}
    calibration = json.loads((folder / "calibration.json").read_text(encoding="utf-8"))
    return {"coefficients": calibration["coefficients"], "chi2_per_dof": calibration["chi2_per_dof"]}


def flatten(row: dict) -> dict:
    """A row of the CSV: per-channel columns for RGB values, warnings joined by '; '."""
    flat = {}
    for key, value in row.items():
        if key in ("fitted", "sigma", "true", "error_vs_true"):
            suffix = {"fitted": "", "sigma": ".sigma", "true": ".true", "error_vs_true": ".error"}[key]
            for name, v in (value or {}).items():
                if isinstance(v, list):
                    for channel, c in zip(CHANNELS, v):
                        flat[f"{name}.{channel}{suffix}"] = c
                else:
                    flat[f"{name}{suffix}"] = v
        elif key == "coefficients":
            flat.update({f"p{k}": c for k, c in enumerate(value)})
        elif key == "warnings":
            flat[key] = "; ".join(value)
        else:
            flat[key] = value
    return flat


def write_summary(manifest) -> tuple:
    """summary.json and summary.csv in the batch's folder; their paths."""
    table = rows(manifest)
    out = manifest.output
    json_path, csv_path = out / "summary.json", out / "summary.csv"
    json_path.write_text(json.dumps(table, indent=2) + "\n", encoding="utf-8")
    flat = [flatten(row) for row in table]
    columns = list(dict.fromkeys(key for row in flat for key in row))
    with open(csv_path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, columns)
        writer.writeheader()
        writer.writerows(flat)
    return json_path, csv_path
