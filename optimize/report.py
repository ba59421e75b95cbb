"""What a fit leaves behind: params.json, convergence.png, comparison.png and the fitted-vs-true table.

params.json's "look" holds every hair control of the result, the fitted ones and those fixed by the target's
scenes: what `warp-hair export` (warp_hair.export) takes to other renderers.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from warp_hair.io import srgb_encode
from warp_hair.model.params import HairParams

from .fit import FitResult
from .latents import SPECS, hair_and_gain
from .target import Target, true_values

CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def errors(result: FitResult, truth: dict) -> dict:
    return {name: (np.asarray(result.values[name]) - np.asarray(truth[name])).tolist() for name in truth}


def fitted_look(result: FitResult, target: Target) -> HairParams:
    """The hair of the target's scenes with the fitted controls put in (exposure is not a hair control)."""
    controls = target.hair.to_dict()
    # A fit's colour control is always the scenes' colour input (latents.parse_control_names), so a plain
    # update keeps the other melanin when only one is fitted.
    controls.update(hair_and_gain(result.values)[0])
    return HairParams(**controls)


def write_params(path: Path, result: FitResult, truth: dict, look: HairParams, extra: dict | None = None) -> None:
    data = {
        "target": result.target,
        "fitted": result.values,
        "look": look.to_dict(),
        "uncertainty": result.uncertainties,
        # uncertainty = √(noise² + model²): the Monte Carlo part and a model_error brightness disagreement's.
        "uncertainty_parts": result.uncertainty_parts,
        "start": result.start,
        "loss": result.loss,
        "iterations": result.iterations,
        "gauss_newton_steps": [{"loss": r.loss, "misfit": r.misfit, "kept": r.accepted} for r in result.history.refine],
        "stop_reason": result.stop_reason,
        "seconds": round(result.seconds, 1),
        "warnings": result.warnings,
        "correlations": result.correlations,
        # The measure of fit (goodness.py) and, for a fit that failed, why (verdict.py): its numbers are no result.
        "goodness_of_fit": None if result.goodness is None else result.goodness.to_dict(),
        "failed": result.failed,
        "failures": result.failures,
    }
    if truth:
        data["true"] = truth
        data["error"] = errors(result, truth)
    data.update(extra or {})
    Path(path).write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def _fmt(value, digits=3) -> str:
    if isinstance(value, (list, tuple, np.ndarray)):
        return "(" + ", ".join(f"{v:.{digits}f}" for v in value) + ")"
    return f"{value:.{digits}f}"


def format_table(result: FitResult, truth: dict, renderer: str | None = None) -> str:
    """A plain-text table: control, fitted ± uncertainty, true, error. Where a model error is counted, the
    uncertainty's noise and model parts get columns of their own and a line says what the model part is;
    `renderer`: who rendered the target, for that line."""
    parts = result.uncertainty_parts or {}
    split = result.uncertainties is not None and parts.get("model_error", 0.0) > 0
    realised = result.uncertainties is not None and parts.get("realisation") is not None
    header = ("control", "fitted", "± 1σ") + (("± noise", "± model") if split else ()) + ("true", "error")
    if realised:
        header = header[:3] + (("± noise", "± model") if split else ("± noise",)) + ("± realisation",) + header[-2:]
    rows = []
    for name, value in result.values.items():
        sigma = ("",) if result.uncertainties is None else (_fmt(result.uncertainties[name]),)
        if split:
            sigma += (_fmt(parts["noise"][name]), _fmt(parts["model"][name]))
        elif realised:
            sigma += (_fmt(parts["noise"][name]),)
        if realised:
            sigma += (_fmt(parts["realisation"][name]),)
        true = truth.get(name)
        rows.append(
            (
                name,
                _fmt(value),
                *sigma,
                "" if true is None else _fmt(true),
                "" if true is None else _fmt(np.asarray(value) - np.asarray(true), 3),
            )
        )
    widths = [max(len(r[k]) for r in [*rows, header]) for k in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if split:
        by = f"{renderer}, which rendered the target," if renderer else "the target's renderer"
        lines.append(
            f"± 1σ = √(noise² + model²{' + realisation²' if realised else ''}); model: what a "
            f"{100 * parts['model_error']:g}% disagreement in brightness between {by} and warp-hair moves the "
            "fit by (--model-error)"
        )
    if realised:
        lines.append(
            "realisation: the spread of the estimate over other realisations of the fibers' recipe, "
            '(realisations = "random": the target\'s strands are one of them)'
        )
    return "\n".join(lines)


def plot_convergence(path: Path, result: FitResult, truth: dict) -> None:
    """The loss and every fitted control against the iteration; true values dashed. Gauss–Newton steps follow
    the Adam iterations as dots; a step undone because its misfit rose beyond its noise (refine.py) is a cross.
    A failed fit says so in the title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result.history.values)
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.2 * (len(names) + 1), 3.0), constrained_layout=True)
    its = np.arange(1, result.iterations + 1)
    ax = axes[0]
    ax.semilogy(its, result.history.loss, color="0.3", lw=0.8, label="Adam")
    refine = result.history.refine
    steps = result.iterations + 1 + np.arange(len(refine))
    kept = [r.accepted for r in refine]
    for x, r in zip(steps, refine):
        ax.plot(
            x, r.loss, "o" if r.accepted else "x", ms=3 if r.accepted else 5, color="0.3" if r.accepted else "tab:red"
        )
    if refine:
        ax.plot([], [], "o", ms=3, color="0.3", label="step kept")
        ax.plot([], [], "x", ms=5, color="tab:red", label="step undone")
        ax.legend(fontsize=6, loc="upper right")
    ax.set_title(
        f"loss ({result.stop_reason})" + ("  FAILED" if result.failed else ""),
        color="tab:red" if result.failed else "k",
    )
    ax.set_xlabel("iteration")
    for ax, name in zip(axes[1:], names):
        values = result.history.values[name].reshape(result.iterations, -1)
        colours = CHANNEL_COLOURS if values.shape[1] == 3 else ("0.2",)
        true = np.atleast_1d(truth[name]) if name in truth else None
        for k in range(values.shape[1]):
            ax.plot(its, values[:, k], color=colours[k], lw=1.0)
            for x, r, keep in zip(steps, refine, kept):
                ax.plot(
                    x, np.atleast_1d(r.values[name])[k], "o" if keep else "x", ms=3 if keep else 4, color=colours[k]
                )
            if true is not None:
                ax.axhline(true[k], color=colours[k], ls="--", lw=1.0)
        spec = SPECS[name]
        ax.set_title(name + ("  (dashed: true)" if true is not None else ""))
        ax.set_xlabel("iteration")
        if not np.isinf(spec.hi):
            ax.set_ylim(spec.lo, spec.hi)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def display_exposure(target_image: np.ndarray) -> float:
    """The exposure target and fit are both shown at, so that brightness differences show: the target's 99th
    percentile at 0.8."""
    return 0.8 / max(float(np.percentile(target_image, 99)), 1e-6)


def plot_comparison(path: Path, result: FitResult, target: Target) -> None:
    """One row per target image: target | fit | difference (fit − target, red brighter, blue darker)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(target.images)
    fig, axes = plt.subplots(n, 3, figsize=(9.0, 3.0 * n), squeeze=False, constrained_layout=True)
    for row, (image, fitted) in enumerate(zip(target.images, result.images)):
        exposure = display_exposure(image.image)
        diff = (fitted - image.image).mean(axis=-1)
        limit = max(float(np.percentile(np.abs(diff), 99)), 1e-6)
        panels = (
            (srgb_encode(image.image * exposure), f"target: {image.name}", None),
            (srgb_encode(fitted * exposure), "fit", None),
            (diff, f"fit − target (±{limit:.3g})", limit),
        )
        for ax, (picture, title, lim) in zip(axes[row], panels):
            if lim is None:
                ax.imshow(picture, interpolation="nearest")
            else:
                shown = ax.imshow(picture, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
                fig.colorbar(shown, ax=ax, shrink=0.8)
            if image.mask is not None:
                ax.contour(image.mask, levels=[0.5], colors="yellow", linewidths=0.6)
            ax.set_title(title)
            ax.axis("off")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out_dir, result: FitResult, target: Target) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    truth = true_values(target, result.values)
    paths = [out_dir / "params.json", out_dir / "convergence.png", out_dir / "comparison.png"]
    extra = {}
    if result.camera is not None:
        extra["camera"] = result.camera
    if any(image.photo is not None for image in target.images):
        extra["photos"] = photo_records(target)
    write_params(paths[0], result, truth, fitted_look(result, target), extra)
    plot_convergence(paths[1], result, truth)
    plot_comparison(paths[2], result, target)
    return paths


def photo_records(target: Target) -> dict:
    """Per photo image: how it was decoded and how many of its pixels the loss leaves out (params.json)."""
    records = {}
    for image in target.images:
        photo = image.photo
        if photo is None:
            continue
        records[image.name] = {
            "file": photo.path.name,
            "format": photo.format,
            "bits": photo.bits,
            "transfer": photo.transfer,
            "pixels": int(photo.clipped.size),
            "clipped": int(photo.clipped.sum()),
            "crushed": int((photo.crushed & ~photo.clipped).sum()),
            "counted": int(image.mask.sum()),
            "exif": photo.exif,
            "notes": photo.notes,
        }
    return records


def photo_summary(target: Target) -> list[str]:
    """One line per photo image: its decoding, and the pixels left out of the loss (what `warp-hair fit` prints)."""
    lines = []
    for _name, r in photo_records(target).items():
        exif = ", ".join(f"{k} {v:g}" for k, v in r["exif"].items())
        lines.append(
            f"{r['file']}: {r['format']} {r['bits']}-bit, {r['transfer']} decoded to linear; "
            f"{r['clipped']} clipped and {r['crushed']} crushed pixels of {r['pixels']} left out of the "
            f"loss" + (f"; EXIF {exif}" if exif else "") + "".join(f"; {n}" for n in r["notes"])
        )
    return lines


def camera_table(result: FitResult, truth: dict | None = None) -> str:
    """The fitted gains and white balance ± 1σ (and the true ones, `truth` as camera_truth.json holds them)."""
    camera = result.camera
    if camera is None:
        return ""
    truth = truth or {}
    modes = camera["modes"]
    lines = [
        f"camera (gains {modes['gains']}, white balance {modes['white_balance']}; the gains scale the render "
        "to the photo, green's white balance is 1):"
    ]
    for name, (value, sigma) in camera["gains"].items():
        true = truth.get("gains", {}).get(name)
        versus = "" if true is None else f"  true {true:.4f}  error {100 * (value / true - 1):+.1f}%"
        lines.append(f"  gain[{name}]  {value:.4f} ± {sigma:.4f}{versus}")
    wb = camera["white_balance"]
    true = truth.get("white_balance")
    lines.append(
        "  white_balance  "
        + _fmt(wb["value"], 4)
        + " ± "
        + _fmt(wb["sigma"], 4)
        + ("" if true is None else "  true " + _fmt(true, 4))
    )
    return "\n".join(lines)
