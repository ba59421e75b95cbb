"""What a fit is asked to do, and what it is held to: `FitSettings`, the sample and step counts derived from them,
and the acceptance bounds. Its own module so that the fit (fit.py), the check before it (identify.py) and the
batch runner read one definition without importing each other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from . import camera
from .latents import DEFAULT_FIT
from .realisations import DEFAULT_SAMPLES
from .refine import REFINABLE_LOSSES

if TYPE_CHECKING:
    from .target import Target

# The acceptance bounds of a fit: its error per component, against the truth (docs/acceptance.md).
ALBEDO_BOUND, BETA_BOUND = 0.02, 0.03
# Hair as it grows (issue 44): the strands' spreads and the tip's absorption factor.
VARIATION_BOUND = 0.05
BOUNDS = {
    "albedo": ALBEDO_BOUND,
    "beta_m": BETA_BOUND,
    "beta_n": BETA_BOUND,
    "color_spread": VARIATION_BOUND,
    "roughness_spread": VARIATION_BOUND,
    "tip_absorption": VARIATION_BOUND,
}
FINAL_SPP_FACTOR = 4
DEFAULT_REFINE_STEPS = 8
# A photo's unknown gains leave a valley along which its albedo trades off against the exposure, and there the
# refinement's own Monte Carlo error at the defaults above came out 2–3× the σ the target's noise gives
# (docs/acceptance.md, "Photographs"): a photo's Gauss–Newton steps render every pixel at the full samples and
# take this many times the steps.
PHOTO_REFINE_FACTOR = 3
# Pixels per image per render at the default sample counts: the shipped own targets' 48×48, at which those were
# chosen. A larger image's iterations render this many of its pixels (`Batches`); its linearisations render all
# of them at proportionally fewer samples (`gauss_newton_spp`).
BATCH_PIXELS = 48 * 48


@dataclass
class FitSettings:
    controls: tuple = DEFAULT_FIT
    iters: int = 60
    spp: int = 16  # at the end of the schedule
    loss: str = "l2"
    pool: int = 4  # compare k×k block averages (losses.py says why)
    lr: float = 0.1
    seed: int = 0
    patience: int = 30
    init: dict = field(default_factory=dict)  # start values of fitted controls; default: each control's neutral guess
    threads: int | None = None
    device: str = "cpu"  # where to render: "cpu", "cuda", "cuda:N" (warp_hair.devices); Adam's state lives there too
    uncertainty: bool = True
    refine: int | None = None  # Gauss–Newton steps after Adam (refine.py); None: `refine_steps`, 0 for L1
    batch: int | None = BATCH_PIXELS  # pixels of an image per render (see BATCH_PIXELS); None: every pixel, always
    # Relative brightness disagreement between the target's renderer and ours, counted in the uncertainties
    # (uncertainty.py); None: 0 for warp-hair's own targets, 0.01 for any other (`target_model_error`).
    model_error: float | None = None
    # "fixed": render the scenes' own fibers; "random": their recipe's other realisations (realisations.py);
    # None: the target's (target.toml `realisations`, default "fixed").
    realisations: str | None = None
    realisation_samples: int = DEFAULT_SAMPLES  # K: realisations rendered at the fitted look for σ's realisation term


def gauss_newton_spp(settings: FitSettings, target: Target) -> int:
    """Samples per pixel of each linearisation's renders: FINAL_SPP_FACTOR × spp, and for an image larger than
    settings.batch proportionally fewer, so that a linearisation renders the same number of paths whatever the
    size, over every pixel (each of them carries the target's information; its noise averages over more of
    them, so fewer samples each give the fit the same precision). A photo's (its gains fitted) at the full samples
    always (PHOTO_REFINE_FACTOR says why)."""
    spp = settings.spp * FINAL_SPP_FACTOR
    if settings.batch is None or camera.fitted(target):
        return spp
    pixels = max(image.image.shape[0] * image.image.shape[1] for image in target.images)
    return max(1, round(spp * min(1.0, settings.batch / pixels)))


def refine_steps(settings: FitSettings, target: Target, target_spp: int | None = None) -> int:
    """settings.refine; by default at least DEFAULT_REFINE_STEPS, and enough that the refinement's renders add up
    to half the samples per pixel the target was rendered with (its scenes' [render] spp). As many points as the
    later half of the steps are averaged into the estimate (refine.py: the end points of steps from settled
    points, which may take fewer steps), so its Monte Carlo variance is then about four times what the target's
    own noise gives it (the reported σ counts both), and a target rendered at more samples to be less noisy
    (fur_patch) gets more steps, and a photo PHOTO_REFINE_FACTOR times as many. refine.py may run more while its
    steps still move. target_spp: the target's samples per pixel, if not its scenes' (`targets check --spp`)."""
    if settings.refine is not None:
        return settings.refine
    if settings.loss not in REFINABLE_LOSSES:
        return 0
    per_step = 2 * gauss_newton_spp(settings, target)  # two passes per linearisation
    target_spp = target_spp or max(image.scene.render.spp for image in target.images)
    steps = max(DEFAULT_REFINE_STEPS, math.ceil(target_spp / (2 * per_step)))
    return steps * (PHOTO_REFINE_FACTOR if camera.fitted(target) else 1)
