"""What a fit leaves behind: params.json, convergence.png, comparison.png and the fitted-vs-true table.

params.json's "look" holds every hair control of the result, the fitted ones and those fixed by the target's
scenes: what `warp-hair export` (warp_hair.export) takes to other renderers.

comparison.png (and the batch report's thumbnails) shows each target image beside the fitted look rendered for
the picture (`render_pictures`): at the target's own samples per pixel, another seed, so that both columns carry
noise of one size, unless that costs more than the fit's Gauss–Newton stage traced, and then at as many samples
as it did. The fit's own last renders, at a few samples, would be speckled beside a target of thousands and
their difference all noise. The difference is shown in units of its expected noise σ (both images' Monte Carlo
standard errors) where the target's noise is known, as a rendered target's is: noise alone stays within ±2σ in
about 95% of the pixels, and a misfit shows as structure beyond it. A photograph's noise is not known; its
difference is shown in radiance.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from warp_hair.io import srgb_encode
from warp_hair.model.params import HairParams
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render

from .fit import FitResult
from .latents import SPECS, hair_and_gain
from .settings import FitSettings, gauss_newton_spp
from .target import Target, made_by, true_values

CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")
# Why the Adam iterations stopped (FitResult.stop_reason), in words.
STOP_REASONS = {
    "iterations": "all that --iters allows",
    "plateau": "stopped where the loss no longer improved",
    "interrupted": "interrupted",
}


def errors(result: FitResult, truth: dict) -> dict:
    return {name: (np.asarray(result.values[name]) - np.asarray(truth[name])).tolist() for name in truth}


def fitted_look(result: FitResult, target: Target) -> HairParams:
    """The hair of the target's scenes with the fitted controls put in (exposure is not a hair control)."""
    controls = target.hair.to_dict()
    # A fit's colour control is always the scenes' colour input (latents.parse_control_names), so a plain
    # update keeps the other melanin when only one is fitted.
    controls.update(hair_and_gain(result.values)[0])
    return HairParams(**controls)


# The difference panel's scale in σ: noise alone is within ±2σ in 95% of the pixels, ±4 leaves room to see more.
SIGMA_SCALE = 4.0
# A pixel's σ is at least this fraction of the target's display white (its 99th percentile): a background that
# both images render exactly (σ = 0) shows no difference below what a display could show, and is not counted.
SIGMA_FLOOR = 1e-3
# A pixel's variance is the mean of its NOISE_WINDOW² neighbours': a dark pixel's own samples rarely hold the rare
# bright paths its distribution has, and its own estimate would call the target's one a misfit. At black_straight's
# truth (1024 spp, seed 2 against the target's 1): 94% (front) and 96% (back) of the pixels within 2σ, against 82%
# and 95% from each pixel's own.
NOISE_WINDOW = 5
PICTURE_SHARE = 4  # a picture renders at most 1/PICTURE_SHARE of the samples the Gauss–Newton stage traced
THUMBNAIL_PX = 160  # the batch report's thumbnails: each image scaled up by a whole factor to about this width


@dataclass(frozen=True)
class Picture:
    """A target image beside the fit, for a person to compare (comparison.png, the batch report's thumbnails)."""

    name: str
    target: np.ndarray  # (H, W, 3) linear radiance
    fit: np.ndarray  # (H, W, 3) the fitted look rendered, exposure (or a photo's gains) applied
    mask: np.ndarray | None  # (H, W) the pixels the loss counts
    spp: int | None  # samples per pixel of `fit`; None: the fit's own last renders (an interrupted fit)
    sigma: np.ndarray | None  # (H, W) the standard error of fit − target, where the target's noise is known
    target_spp: int | None = None  # the target's samples per pixel, where a renderer made it

    @property
    def exposure(self) -> float:
        return display_exposure(self.target)

    def z(self) -> tuple[np.ndarray, np.ndarray]:
        """((fit − target) / σ of the channel means, the pixels that carry noise (and count, where masked))."""
        floor = SIGMA_FLOOR / self.exposure
        counted = self.sigma > floor
        if self.mask is not None:
            counted &= self.mask
        return (self.fit - self.target).mean(axis=-1) / np.maximum(self.sigma, floor), counted

    def within_2_sigma(self) -> float | None:
        """The share of the noisy pixels within ±2σ: about 95% where the difference is noise alone."""
        z, counted = self.z()
        return float(np.mean(np.abs(z[counted]) < 2.0)) if counted.any() else None

    def difference(self) -> tuple[np.ndarray, float, str]:
        """(values, limit, title) of the difference panel, the channels averaged: (fit − target) / σ on
        ±SIGMA_SCALE where σ is known, else fit − target on ± its 99th percentile."""
        if self.sigma is None:
            diff = (self.fit - self.target).mean(axis=-1)
            limit = max(float(np.percentile(np.abs(diff), 99)), 1e-6)
            return diff, limit, f"fit − target (±{limit:.3g})\nthe target's noise unknown"
        within = self.within_2_sigma()
        share = "" if within is None else f"{100 * within:.0f}% within ±2σ"
        return self.z()[0], SIGMA_SCALE, f"(fit − target) / σ: {share}\n(noise alone: 95%)"

    def record(self) -> dict:
        """What params.json says of the picture: the samples the fit column had, and how the difference reads."""
        record = {"spp": self.spp, "difference": "radiance" if self.sigma is None else "sigma"}
        if self.sigma is not None:
            record["target_spp"] = self.target_spp
            within = self.within_2_sigma()
            record["within_2_sigma"] = None if within is None else round(within, 4)
            record["median_sigma"] = float(np.median(self.sigma[self.z()[1]])) if self.z()[1].any() else 0.0
        return record


def difference_caption(record: dict | None) -> str:
    """The difference panel's caption from params.json's picture record (the batch report's thumbnails)."""
    if not record or record.get("difference") != "sigma":
        return "fit − target"
    within = record.get("within_2_sigma")
    return f"(fit − target) / σ, ±{SIGMA_SCALE:g}σ" + ("" if within is None else f": {100 * within:.0f}% within ±2σ")


def picture_spp_cap(result: FitResult, settings: FitSettings, target: Target) -> int:
    """The most samples per pixel a picture renders: a quarter of what the fit's Gauss–Newton stage traced per pixel
    (its steps and the final linearisation, two passes each), so that the picture adds about a tenth to a fit's
    time (at the whole stage's samples it added 40–60% to the Quick start's fit); its difference panel is in units
    of both images' noise, so fewer samples widen the band, not the verdict."""
    return max(1, (len(result.history.refine) + 1) * 2 * gauss_newton_spp(settings, target) // PICTURE_SHARE)


def render_pictures(
    result: FitResult, target: Target, settings: FitSettings | None = None, progress: bool = False
) -> list[Picture]:
    """Each target image beside the fitted look rendered for the picture (the module docstring says how): at its
    scene's [render] spp, capped by `picture_spp_cap`, with that seed + 1. An interrupted fit's pictures, or
    those a Ctrl-C stops, are the fit's own last renders (no σ)."""
    from tqdm import tqdm

    own = [
        Picture(image.name, image.image, fitted, image.mask, None, None)
        for image, fitted in zip(target.images, result.images)
    ]
    if result.stop_reason == "interrupted":
        return own
    settings = settings or FitSettings()
    look, cap = fitted_look(result, target), picture_spp_cap(result, settings, target)
    noise_known = target.origin != "unknown"
    pixels = [image.image.shape[0] * image.image.shape[1] for image in target.images]
    pictures = []
    with tqdm(total=sum(pixels), unit="px", desc="comparison.png", disable=not progress) as bar:
        try:
            for k, (image, gain) in enumerate(zip(target.images, picture_gains(result, target))):
                spp, before = min(image.scene.render.spp, cap), sum(pixels[:k])

                def advance(done, _total, before=before):
                    bar.update(before + done - bar.n)

                fitted, stderr = render(
                    prepare(image.scene, settings.device).with_hair(look),
                    spp=spp,
                    seed=(image.scene.render.seed + 1) % 2**32,
                    threads=settings.threads,
                    progress=advance,
                    return_stderr=True,
                )
                sigma, target_spp = None, None
                if noise_known and image.photo is None:
                    target_spp = image.scene.render.spp
                    # The channels of a path move together: the channel mean's σ is about the mean of theirs. The
                    # target's noise is this render's per sample, at the target's samples.
                    variance = window_mean(((gain * stderr).mean(axis=-1)) ** 2, NOISE_WINDOW)
                    sigma = np.sqrt(variance * (1.0 + spp / target_spp))
                pictures.append(Picture(image.name, image.image, gain * fitted, image.mask, spp, sigma, target_spp))
        except KeyboardInterrupt:
            return own
    return pictures


def window_mean(values: np.ndarray, size: int) -> np.ndarray:
    """The mean of each pixel's size × size neighbourhood (the edge pixels repeated beyond the image)."""
    pad = size // 2
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(values, pad, mode="edge"), (size, size))
    return windows.mean(axis=(-2, -1))


def picture_gains(result: FitResult, target: Target) -> list:
    """Per target image, what multiplies a render of the fitted look: the exposure, or a photo's fitted gain
    times the white balance (camera.py), per channel."""
    if result.camera is None:
        return [np.float32(hair_and_gain(result.values)[1])] * len(target.images)
    white_balance = np.asarray(result.camera["white_balance"]["value"], dtype=np.float32)
    return [np.float32(result.camera["gains"][image.name][0]) * white_balance for image in target.images]


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


def describe_run(iterations: int, stop_reason: str, refine=()) -> str:
    """ "60 Adam iterations (all that --iters allows), then 8 Gauss–Newton steps (7 kept)": what the fit ran."""
    text = f"{iterations} Adam iteration{'s' * (iterations != 1)} ({STOP_REASONS.get(stop_reason, stop_reason)})"
    if refine:
        kept = sum(step.accepted for step in refine)
        text += f", then {len(refine)} Gauss–Newton step{'s' * (len(refine) != 1)} ({kept} kept)"
    return text


def _fmt(value, digits=3) -> str:
    if isinstance(value, (list, tuple, np.ndarray)):
        return "(" + ", ".join(f"{v:.{digits}f}" for v in value) + ")"
    return f"{value:.{digits}f}"


def format_table(result: FitResult, truth: dict, renderer: str | None = None) -> str:
    """A plain-text table: control, fitted ± uncertainty, and where `truth` has values, true and error. Where a
    model error is counted, the uncertainty's noise and model parts get columns of their own and a line says what
    the model part is; `renderer`: who rendered the target (`Target.origin`), for that line."""
    parts = result.uncertainty_parts or {}
    split = result.uncertainties is not None and parts.get("model_error", 0.0) > 0
    realised = result.uncertainties is not None and parts.get("realisation") is not None
    ranged = result.uncertainties is not None and parts.get("range") is not None
    versus = ("true", "error") if truth else ()
    header = ("control", "fitted", "± 1σ") + (("± noise", "± model") if split else ())
    if realised:
        header = header[:3] + (("± noise", "± model") if split else ("± noise",)) + ("± realisation",)
    if ranged:
        header += ("± noise",) if not (split or realised) else ()
        header += ("± range",)
    header += versus
    rows = []
    for name, value in result.values.items():
        sigma = ("",) if result.uncertainties is None else (_fmt(result.uncertainties[name]),)
        if split:
            sigma += (_fmt(parts["noise"][name]), _fmt(parts["model"][name]))
        elif realised:
            sigma += (_fmt(parts["noise"][name]),)
        if realised:
            sigma += (_fmt(parts["realisation"][name]),)
        if ranged:
            sigma += (_fmt(parts["noise"][name]),) if not (split or realised) else ()
            sigma += (_fmt(parts["range"][name]),)
        true = truth.get(name)
        if not versus:
            rows.append((name, _fmt(value), *sigma))
        elif true is None:
            rows.append((name, _fmt(value), *sigma, "", ""))
        else:
            rows.append((name, _fmt(value), *sigma, _fmt(true), _fmt(np.asarray(value) - np.asarray(true), 3)))
    widths = [max(len(r[k]) for r in [*rows, header]) for k in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [header, *rows]]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if split:
        by = "the target" + (f" ({made_by(renderer)})" if renderer else "")
        lines.append(
            f"± 1σ = √(noise² + model²{' + realisation²' if realised else ''}{' + range²' if ranged else ''}); "
            "model: what a "
            f"{100 * parts['model_error']:g}% disagreement in brightness between {by} and warp-hair's renders "
            "moves the fit by (--model-error)"
        )
    if ranged:
        lines.append(
            "range: along a direction the images do not determine at the fit's noise, what the controls' ranges "
            "allow (the warning below names it)"
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


def plot_comparison(path: Path, pictures: list[Picture]) -> None:
    """One row per target image: target | fit | difference (red where the fit is brighter, blue darker)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(pictures)
    fig, axes = plt.subplots(n, 3, figsize=(9.0, 3.2 * n), squeeze=False, constrained_layout=True)
    for row, picture in enumerate(pictures):
        diff, limit, diff_title = picture.difference()
        fit_title = "fit (its last render)" if picture.spp is None else f"fit ({picture.spp} spp, another seed)"
        made_at = "" if picture.target_spp is None else f" ({picture.target_spp} spp)"
        panels = (
            (srgb_encode(picture.target * picture.exposure), f"target: {picture.name}{made_at}", None),
            (srgb_encode(picture.fit * picture.exposure), fit_title, None),
            (diff, diff_title, limit),
        )
        for ax, (shown, title, lim) in zip(axes[row], panels):
            if lim is None:
                ax.imshow(shown, interpolation="nearest")
            else:
                image = ax.imshow(shown, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
                fig.colorbar(image, ax=ax, shrink=0.8, label="σ" if picture.sigma is not None else None)
            if picture.mask is not None:
                ax.contour(picture.mask, levels=[0.5], colors="yellow", linewidths=0.6)
            ax.set_title(title, fontsize=10)
            ax.axis("off")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_thumbnails(folder: Path, pictures: list[Picture]) -> list[Path]:
    """target_<image>.png, fit_<image>.png and diff_<image>.png: comparison.png's panels as pictures of their own
    (the batch report's), each scaled up by a whole factor to about THUMBNAIL_PX."""
    from matplotlib import colormaps
    from PIL import Image

    paths = []
    for picture in pictures:
        diff, limit, _title = picture.difference()
        panels = {
            "target": srgb_encode(picture.target * picture.exposure),
            "fit": srgb_encode(picture.fit * picture.exposure),
            "diff": colormaps["RdBu_r"](np.clip(0.5 + 0.5 * diff / limit, 0.0, 1.0))[..., :3],
        }
        for kind, panel in panels.items():
            pixels = Image.fromarray(np.round(255 * panel).astype(np.uint8))
            scale = max(1, THUMBNAIL_PX // max(pixels.size))
            paths.append(Path(folder) / f"{kind}_{picture.name}.png")
            pixels.resize((pixels.width * scale, pixels.height * scale), Image.NEAREST).save(paths[-1])
    return paths


def write_outputs(
    out_dir,
    result: FitResult,
    target: Target,
    settings: FitSettings | None = None,
    progress: bool = False,
    thumbnails: bool = False,
) -> list[Path]:
    """params.json, convergence.png and comparison.png in `out_dir` (and with `thumbnails` the batch report's
    pictures); `settings`: the fit's, for where and at how many samples the picture renders (`render_pictures`)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    truth = true_values(target, result.values)
    paths = [out_dir / "params.json", out_dir / "convergence.png", out_dir / "comparison.png"]
    pictures = render_pictures(result, target, settings, progress)
    extra = {"picture": {picture.name: picture.record() for picture in pictures}}
    if result.camera is not None:
        extra["camera"] = result.camera
    if result.arrangement is not None:
        extra["arrangement"] = result.arrangement
    if any(image.photo is not None for image in target.images):
        extra["photos"] = photo_records(target)
    write_params(paths[0], result, truth, fitted_look(result, target), extra)
    plot_convergence(paths[1], result, truth)
    plot_comparison(paths[2], pictures)
    if thumbnails:
        paths += write_thumbnails(out_dir, pictures)
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
    for name, weight in camera.get("card_weights", {}).items():
        lines.append(
            f"  grey card in {name}: a block of it weighs {weight:.3g}x one of the hair's (their residuals' "
            "variances, at the descent's estimate)"
        )
    return "\n".join(lines)


def arrangement_table(result: FitResult) -> str:
    """How the strands lie, estimated at the fit's end ± 1σ, and its share of the look's σ (arrangement.py)."""
    found = result.arrangement
    if found is None:
        return ""
    lines = ["arrangement (target.toml [arrangement]; the look above is averaged over its prior):"]
    for key, entry in found["estimate"].items():
        low, high = entry["prior"]
        lines.append(f"  {key}  {entry['value']:.4g} ± {entry['sigma']:.2g}  (prior [{low:g}, {high:g}])")
    shares = found["look_share_of_variance"]
    lines.append(
        "  its share of the look's variance: " + ", ".join(f"{label} {100 * v:.0f}%" for label, v in shares.items())
    )
    outside = found.get("look_at_estimate_outside") or []
    if outside:
        lines.append(
            f"  the look at that arrangement: beyond one linear step ({', '.join(outside)} outside the controls' "
            "ranges; params.json has the step)"
        )
    else:
        lines.append("  the look at that arrangement: " + _describe_look(found["look_at_estimate"]))
    return "\n".join(lines)


def _describe_look(values: dict) -> str:
    return " ".join(f"{name}={_fmt(value)}" for name, value in values.items())
