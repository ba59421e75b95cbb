"""report.html: the batch as one self-contained page that a person reads in a browser.

Every picture is inlined as a data: URI and the style sits in the page, so the file can be mailed, attached to a
ticket or opened from any folder. Per fit: target | fit | difference thumbnails for each of its images (one
exposure for target and fit; the difference red where the fit is brighter, blue where darker), the fitted
controls against the truth with their 1σ, the convergence plot and the export snippets; per render its preview;
per calibration its coefficients and table; per failed job its error; per job the retries it cost and its
warnings. Numbers are printed with `number` (values) and `sigma` (uncertainties), the same everywhere.
"""

from __future__ import annotations

import base64
import datetime
import html
import json
from pathlib import Path

from . import store
from .summary import rows

CHANNELS = ("R", "G", "B")
STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em; color: #222; max-width: 80em; }
table { border-collapse: collapse; margin: 0.5em 0 1em; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: right; }
th { background: #f3f3f3; } td.name, th.name { text-align: left; }
.done { color: #17702c; } .failed { color: #b00020; } .pending { color: #8a6d00; }
section { border-top: 2px solid #ddd; margin-top: 1.5em; }
figure { display: inline-block; margin: 0.3em; text-align: center; } figcaption { font-size: 0.85em; }
img.thumb { image-rendering: pixelated; width: 160px; } img.plot { max-width: 100%; }
pre { background: #f6f6f6; padding: 0.6em; overflow-x: auto; font-size: 0.85em; }
.warning { color: #8a4b00; } .retried { color: #8a6d00; }
"""


def number(value) -> str:
    return f"{value:.4f}"


def sigma(value) -> str:
    return f"{value:.2g}"


def write_report(manifest) -> Path:
    """Write OUT/report.html from what the batch's folder holds now; its path."""
    table = rows(manifest)
    counts = {s: sum(r["status"] == s for r in table) for s in ("done", "failed", "pending")}
    parts = [
        f"<h1>warp-hair batch: {_e(manifest.path.name)}</h1>",
        f"<p>{counts['done']} done, {counts['failed']} failed, {counts['pending']} pending; written "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC. The table is also in "
        "summary.csv and summary.json beside this page.</p>",
        _overview(table),
    ]
    groups = manifest.groups()
    for row in table:
        folder = store.job_dir(manifest.output, row["name"])
        parts.append(
            f'<section id="{_e(row["name"])}"><h2>{_e(row["name"])} '
            f'<small class="{row["status"]}">({row["kind"]}, {row["status"]})</small></h2>'
        )
        if row["retries"]:
            parts.append(f'<p class="retried">{_retried(row["retries"])}</p>')
        if row["status"] == "failed":
            parts.append(f'<p class="failed">{_e(row["error"])}</p>')
            if (folder / "convergence.png").exists():  # a failed fit leaves its course to look at
                parts.append(f'<img class="plot" src="{_data(folder / "convergence.png")}" alt="convergence">')
        elif row["status"] == "done":
            parts.append(
                {"fit": _fit, "render": _render, "calibrate": _calibrate}[row["kind"]](
                    row, folder, groups[row["name"]][0]
                )
            )
        if row.get("warnings"):
            parts.append("<ul>" + "".join(f'<li class="warning">{_e(w)}</li>' for w in row["warnings"]) + "</ul>")
        parts.append("</section>")
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>warp-hair batch {_e(manifest.path.name)}</title><style>{STYLE}</style></head><body>\n"
        + "\n".join(parts)
        + "\n</body></html>\n"
    )
    path = manifest.output / "report.html"
    path.write_text(page, encoding="utf-8")
    return path


def _overview(table) -> str:
    lines = ['<table><tr><th class="name">job</th><th>kind</th><th>status</th><th>seconds</th><th>retries</th></tr>']
    for row in table:
        seconds = "" if row["seconds"] is None else f"{row['seconds']:.1f}"
        retries = "" if row["retries"] is None else str(row["retries"])
        lines.append(
            f'<tr><td class="name"><a href="#{_e(row["name"])}">{_e(row["name"])}</a></td><td>{row["kind"]}'
            f'</td><td class="{row["status"]}">{row["status"]}</td><td>{seconds}</td><td>{retries}</td></tr>'
        )
    return "\n".join(lines) + "</table>"


def _retried(retries: int) -> str:
    return f"retried {retries} time{'s' if retries > 1 else ''}: its worker died (killed, out of memory, a lost node)"


def _fit(row, folder: Path, job) -> str:
    from ..report import describe_run, difference_caption

    out = [
        f"<p>target {_e(row['target'])}: {_e(describe_run(row['iterations'], row['stop_reason']))}, "
        f"loss {row['loss']:.4g}, {row['seconds']:.1f} s"
        + ("" if row.get("chi2_per_dof") is None else f"; measure of fit χ²/dof {row['chi2_per_dof']:.2f}")
        + "</p>"
    ]
    # How comparison.png's fit column was rendered and its difference reads (optimize/report.py).
    pictures = json.loads((folder / "params.json").read_text(encoding="utf-8")).get("picture", {})
    for name in _image_names(folder):
        picture = pictures.get(name) or {}
        fit = "fit" if picture.get("spp") is None else f"fit, {picture['spp']} spp"
        captions = (("target", f"target: {_e(name)}"), ("fit", fit), ("diff", _e(difference_caption(picture))))
        figures = "".join(
            f'<figure><img class="thumb" src="{_data(folder / f"{kind}_{name}.png")}" alt="{kind} {_e(name)}">'
            f"<figcaption>{caption}</figcaption></figure>"
            for kind, caption in captions
        )
        out.append(f"<div>{figures}</div>")
    out.append(_controls_table(row))
    out.append(f'<img class="plot" src="{_data(folder / "convergence.png")}" alt="convergence of {_e(row["name"])}">')
    for path in sorted(folder.glob("hair_*")):
        out.append(
            f"<details open><summary>{_e(path.name)}</summary><pre>{_e(path.read_text(encoding='utf-8'))}"
            "</pre></details>"
        )
    return "\n".join(out)


def _image_names(folder: Path) -> list:
    return sorted(p.name[len("target_") : -len(".png")] for p in folder.glob("target_*.png"))


def _controls_table(row) -> str:
    has_truth = bool(row["true"])
    header = (
        '<tr><th class="name">control</th><th>fitted</th><th>± 1σ</th>'
        + ("<th>true</th><th>error</th>" if has_truth else "")
        + "</tr>"
    )
    lines = ["<table>", header]
    for name, value in row["fitted"].items():
        values = value if isinstance(value, list) else [value]
        for k, v in enumerate(values):
            label = name + (f" {CHANNELS[k]}" if len(values) == 3 else "")
            s = _component((row["sigma"] or {}).get(name), k)
            cells = [number(v), "" if s is None else sigma(s)]
            if has_truth:
                t, e = _component(row["true"].get(name), k), _component(row["error_vs_true"].get(name), k)
                cells += ["" if t is None else number(t), "" if e is None else number(e)]
            lines.append(f'<tr><td class="name">{_e(label)}</td>' + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return "\n".join(lines) + "</table>"


def _component(value, k):
    if value is None:
        return None
    return value[k] if isinstance(value, list) else value


def _render(row, folder: Path, job) -> str:
    return (
        f"<p>{row['spp']} spp, seed {row['seed']}, in {row['parts']} part(s), {row['seconds']:.1f} s of "
        f"tasks; image.exr and stderr.exr beside this page's jobs/{_e(row['name'])}/</p>"
        f'<img class="plot" src="{_data(folder / "preview.png")}" alt="render {_e(row["name"])}">'
    )


def _calibrate(row, folder: Path, job) -> str:
    record = json.loads((folder / "calibration.json").read_text(encoding="utf-8"))
    coefficients = ", ".join(f"{p:.6g}" for p in record["coefficients"])
    return (
        f"<p>P(β_n) coefficients p_0..p_5: {coefficients}; χ²/dof {record['chi2_per_dof']:.2f}; "
        f"{row['seconds']:.1f} s</p><pre>{_e((folder / 'calibration.txt').read_text(encoding='utf-8'))}</pre>"
    )


def _data(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _e(text) -> str:
    return html.escape(str(text))
