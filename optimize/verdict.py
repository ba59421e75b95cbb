"""Whether a fit found the look, or failed: failures said as failures, never a result with a small σ.

A fit fails, and `warp-hair fit` exits with FAILED_STATUS, when

- its loss at the result is above its first iteration's (which renders fewer samples, so carries more of our
  noise), or its refinement ended worse than it started beyond noise (refine.py keeps that from happening; the
  check stays as the promise);
- a fitted control ran to the end of its range (within BOUND_FRACTION of it): the latents (latents.py) never
  reach a bound, so a control there is one the images pushed as far as the range lets it go, where a
  convergent fit would have stopped: albedo 0 behind a gain of 343 on a bright photo, say (not where the end is
  the control's default, a spread's 0: images without variation take it there);
- a fitted control does not change the rendered images at the result (its σ would be 0 and mean nothing);
- a photo's gain or white balance ran to a value its images cannot support: a σ above half its value, or a
  white balance beyond WHITE_BALANCE_RANGE (no camera's channel multipliers do that);
- the measure of fit (goodness.py) says that the model does not describe the images: χ²/dof above
  FAILED_CHI2 and significantly above 1, in total or in one view. A photo's own noise (sensor, JPEG) is not in
  the noise model, so a heavily compressed photo can fail so at its truth: the message says to try a lossless
  one.

Each reason says what happened and what to try. The numbers stay in params.json, marked failed, for whoever
wants to look at them; they are not a result.
"""

from __future__ import annotations

import numpy as np

from warp_hair.controls import CONTROLS

from .latents import SPECS, flat_values
from .refine import BEST_Z
from .uncertainty import component_labels

FAILED_STATUS = 3  # the exit status of a fit that failed (0 fitted, 1 a bug, 2 bad input, 130 interrupted)
BOUND_FRACTION = 0.005  # a control within this share of its range's width from an end is at the bound
GAIN_RELATIVE_SIGMA = 0.5  # a gain or white balance uncertain by more than half its value is not supported
WHITE_BALANCE_RANGE = (0.2, 5.0)  # camera white balance multipliers, relative to green
# χ²/dof above which the fitted look does not describe the images. The 29 fits of docs/acceptance.md's issue-42
# run that found their look (own, Cycles, Mitsuba and photo-like targets, fixed and random strands, a Blender
# groom) ended at 0.92–1.21; a photo fitted over random realisations whose refinement stuck at albedo 0.22 for a
# true 0.45 ended at 1.73 with σ 0.026, and a wavy swatch fitted with a straight rig at 27.8.
FAILED_CHI2 = 1.5


def failures(
    values: dict, loss_history, final_loss: float, refinement, camera_report, goodness, undetermined=()
) -> list[str]:
    """Why the fit failed (module docstring), each reason with what to try; empty when it did not. loss_history:
    the descent's losses; final_loss: the fit's at its result (the same image loss, of the final renders);
    undetermined: the fitted components that do not change the images there (`Uncertainty.undetermined`)."""
    reasons = []
    reasons += _loss_rose(loss_history, final_loss, refinement)
    reasons += _at_bounds(values)
    if undetermined:
        reasons.append(
            f"{', '.join(undetermined)} do{'es' if len(undetermined) == 1 else ''} not change the rendered images at "
            "the result, so the images cannot say its value (a σ of 0 there would mean nothing): fix it "
            "(--fix NAME=VALUE), or start the fit where it acts (--init)"
        )
    reasons += _camera(camera_report)
    # In total, or in one view: a view the look does not describe can hide behind another that fits within its
    # noise (a swatch's back-lit view behind a front-lit one whose strands' draw is large noise).
    misfit = [view for view in goodness.views if view.significant and view.ratio > FAILED_CHI2] if goodness else []
    if goodness is not None and ((goodness.significant and goodness.ratio > FAILED_CHI2) or misfit):
        worst = goodness.worst_view()
        reasons.append(
            f"the fitted look does not describe the images: chi2/dof {goodness.ratio:.1f} (1 is noise alone), worst "
            f"in view {worst.name} ({worst.ratio:.1f}), in {worst.region} ({worst.region_ratio:.1f}). Likely "
            "causes: strands that differ from the scenes' (their arrangement, waves, density: a recipe that does "
            "not state them), strands that vary in colour or roughness, lights or a camera other than the scenes', "
            "or a control held fixed at a wrong value, or a refinement stuck away from the look; check the scenes "
            "against the photos, fit more controls (--fit), start elsewhere (--init), or mask the region (a mask "
            "image in target.toml)"
            + _variation_hint(values)
            + (
                "; a photo's own noise (sensor, JPEG compression) counts as misfit here: with a heavily compressed "
                "JPEG, try the photo as PNG, TIFF or raw"
                if goodness.photo
                else ""
            )
        )
    return reasons


def _loss_rose(loss_history, final_loss: float, refinement) -> list[str]:
    reasons = []
    history = np.asarray(loss_history, dtype=np.float64)
    # The fit's loss at its result against its first iteration's: the same image loss, and the first iteration
    # renders a quarter of the samples, so its loss carries more of our noise. An end above it is no noise.
    # (The descent alone may rise where it starts at the optimum: its first steps are noisy; what counts is
    # where the fit ends.)
    if len(history) and np.isfinite(final_loss) and final_loss > float(history[0]):
        reasons.append(
            f"the fit's loss ended above where it started ({float(history[0]):.4g} -> {final_loss:.4g}): lower "
            "the learning rate (--lr), start nearer (--init), or fit with more iterations (--iters)"
        )
    if refinement is not None and refinement.start_misfit is not None and refinement.end_misfit is not None:
        (start, s0), (end, s1) = refinement.start_misfit, refinement.end_misfit
        noise = float(np.hypot(s0, s1))
        if end - start > BEST_Z * noise:
            reasons.append(
                f"the Gauss-Newton refinement ended worse than it started (misfit {start:.4g} -> {end:.4g}, "
                f"{(end - start) / noise:.1f} standard errors): fit again with --refine 0, or from another start "
                "(--init)"
            )
    return reasons


def _variation_hint(values: dict) -> str:
    """The --fit that adds the strands' spread or the tips' change, where the fit held them fixed."""
    fitted = [name for name in values if name in CONTROLS]
    hints = []
    spreads = [name for name in ("color_spread", "roughness_spread") if name not in values]
    if spreads:
        hints.append(f"if the strands vary from one to the next, fit their spread: --fit {','.join(fitted + spreads)}")
    tips = [name for name in ("tip_absorption", "tip_length") if name not in values]
    if tips:
        hints.append(f"if the tips are lighter or darker than the roots: --fit {','.join(fitted + tips)}")
    return "".join(f"; {hint}" for hint in hints)


def _at_bounds(values: dict) -> list[str]:
    reasons = []
    names = list(values)
    labels = component_labels(names)
    flat = flat_values(values)
    owners = [name for name in names for _ in range(SPECS[name].size)]
    for label, owner, x in zip(labels, owners, flat):
        spec = SPECS[owner]
        if not np.isfinite(spec.hi):
            continue
        width = spec.hi - spec.lo
        if x - spec.lo < BOUND_FRACTION * width or spec.hi - x < BOUND_FRACTION * width:
            end = spec.lo if x - spec.lo < spec.hi - x else spec.hi
            if owner in CONTROLS and end == CONTROLS[owner].default:
                continue  # a spread's 0, no variation: the images show none, a value like any other
            reasons.append(
                f"{label} ran to the end of its range ({x:.4g}, the range ends at {end:g}): the images pushed it "
                "as far as it can go, so no value of it describes them. Check the target's scenes (lights, "
                "camera, the fixed controls), fit another control with it, or start elsewhere (--init)"
            )
    return reasons


def _camera(report: dict | None) -> list[str]:
    if report is None:
        return []
    reasons = []
    # What is left to pin a gain: EXIF where the views' exposures are not tied yet, a grey card where none is in
    # view; with both, the hair outweighs the card, and the advice is to look at what the card and hair disagree on.
    exif = report.get("modes", {}).get("gains") == "exif"
    cards = report.get("cards", [])
    if not exif:
        remedy = (
            'give the photos\' exposures (gains = "exif"), a grey card in the shot, or fix the exposure '
            '(gains = "none")'
        )
    elif not cards:
        remedy = 'give a grey card in the shot, or fix the exposure (gains = "none")'
    else:
        remedy = (
            f"the grey card in view {', '.join(cards)} is outweighed by the hair, which the scenes do not describe "
            "well enough to hold its brightness (the report's χ² per region says where): check the recipe and the "
            "lights against the photos, and the card's mask, reflectance and normal"
        )
    for name, (value, sigma) in report["gains"].items():
        if not np.isfinite(value) or value <= 0 or sigma > GAIN_RELATIVE_SIGMA * value:
            reasons.append(
                f"the gain of view {name} ran to {value:.4g} ± {sigma:.3g}, which its images cannot support: {remedy}"
            )
    wb = report["white_balance"]
    balance = (
        f"the grey card in view {', '.join(cards)} does not hold it against the hair: check the recipe and the "
        "lights against the photos, and the card's mask and reflectance"
        if cards
        else 'photograph a grey card, or give the white balance (white_balance = "none" for images already balanced)'
    )
    for channel, value, sigma in zip("rgb", wb["value"], wb["sigma"]):
        low, high = WHITE_BALANCE_RANGE
        if not low <= value <= high or sigma > GAIN_RELATIVE_SIGMA * value:
            reasons.append(
                f"the white balance's {channel} ran to {value:.4g} ± {sigma:.3g}, outside what a camera does "
                f"({low:g} to {high:g}) or unsupported: {balance}"
            )
    return reasons
