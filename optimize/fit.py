"""Fit hair controls to the images of a target by stochastic gradient descent on the renders.

    from optimize import fit, load_target
    result = fit(load_target("targets/blonde_straight"))          # albedo, beta_m, beta_n from a neutral guess
    result.values, result.uncertainties, result.warnings

Each iteration renders every image of the target at the current controls as two independent renders of spp/2 each
(`warp_hair.torch.render_torch_pair`: one gradient pass per render gives its image and its Jacobian, and each
render's adjoint meets the other's Jacobian, so the gradient is unbiased without `render_torch`'s separate forward
render, which would cost a forward pass more per iteration), sums the image losses, and takes one torch.optim.Adam
step on the controls' latents (`latents.py`: no step leaves a control's range). Fresh seeds every iteration, so the
Monte Carlo noise averages out over the iterations instead of biasing every step alike. An image larger than `batch`
pixels is rendered on a random mini-batch of its loss blocks each iteration (`Batches`), so an iteration costs the
same whatever the size.

Schedules: the samples per pixel grow from spp/4 over the first quarter of the iterations to spp/2 and then spp
(noisy, cheap steps while far away; precise ones near the optimum), and the learning rate stays at lr for the first
60% of the iterations, then decays on a cosine to lr/20. The estimate is the mean of the controls over the last
fifth of the iterations run (averaging the iterates of a noisy descent reduces their spread further than a smaller
step would). The fit stops early when the smoothed loss has not improved by 0.1% for `patience` iterations at the
final spp; Ctrl-C stops it too, and the estimate so far is returned (stop_reason "interrupted").

Then a few Gauss–Newton (Levenberg–Marquardt) steps from that estimate (`refine.py`: Adam crawls along the
valleys where controls trade off, Gauss–Newton crosses them), and from the loss linearised at the result, at
4 × spp per render, the final images and loss and, unless interrupted, each control's uncertainty and
identifiability (`uncertainty.py`). Ctrl-C during the refinement keeps its best step so far.

The code follows those stages: `fit` makes a `FitRun`, which holds the state of the descent (latents, Adam,
prepared scenes, the record so far) and advances it one iteration per `step()`, as Warp's examples' `step()`
does; `descend`, `refine`, `evaluate` and `uncertainty` each return a frozen result (`Descent`, `Refinement`,
`Evaluation`, `Uncertainty`), and `result` builds the `FitResult` from them once.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import warp as wp
from tqdm import tqdm

from warp_hair.devices import check_device
from warp_hair.model.params import effective_beta
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render
from warp_hair.torch import render_torch_pair, scene_with_controls

from . import card_region
from .arrangement import columns as arrangement_columns
from .arrangement import estimate as estimate_arrangement
from .arrangement import record as arrangement_record
from .goodness import Goodness, goodness_of_fit, quantisation_variances
from .latents import SPECS, as_values, hair_and_gain, parse_control_names
from .linearize import Linearization, linearize
from .losses import LOSSES, image_loss, loss_scale
from .nuisance import Nuisance
from .realisations import Realisations, RealisationTerm, check_mode, realisation_term
from .refine import REFINABLE_LOSSES, GaussNewton, GaussNewtonStep, Refinement
from .settings import (
    BOUNDS,
    FINAL_SPP_FACTOR,
    FitSettings,
    gauss_newton_spp,
    refine_steps,
)
from .target import Target, interpenetration_note
from .uncertainty import (
    Uncertainty,
    brightness_sensitivity,
    check_model_error,
    component_labels,
    estimate_uncertainty,
    pinned,
    target_model_error,
)
from .verdict import failures

SPP_STAGES = ((0.25, 4), (0.5, 2), (1.0, 1))  # (fraction of the iterations, divisor of spp) in order
FINAL_LR_FRACTION = 0.05
CONSTANT_LR_FRACTION = 0.6
PLATEAU_TOLERANCE = 1e-3
SMOOTHING = 0.9  # of the loss's exponential moving average, for the plateau test
AVERAGED_FRACTION = 0.2


@dataclass(frozen=True)
class History:
    """The fit's course: per Adam iteration its loss, samples per pixel and learning rate, and each fitted
    control's value ((iterations,) or (iterations, 3) for an RGB control); then every Gauss–Newton step tried."""

    loss: np.ndarray
    spp: np.ndarray
    lr: np.ndarray
    values: dict  # control → array of its values, one row per iteration
    refine: tuple[GaussNewtonStep, ...] = ()


@dataclass(frozen=True)
class FitResult:
    target: str
    values: dict  # fitted control → float, or list of 3 for RGB controls
    uncertainties: dict | None  # the same shapes; None when not estimated
    loss: float  # at the fitted controls, from the final evaluation
    start: dict
    history: History
    iterations: int  # Adam iterations run
    stop_reason: str  # "plateau", "iterations" or "interrupted"
    seconds: float
    images: list  # the fitted renders (H, W, 3) of the final evaluation, one per target image
    warnings: list = field(default_factory=list)
    correlations: dict = field(default_factory=dict)  # "a/b" → correlation of the two estimates
    uncertainty_parts: dict | None = None  # the noise, model-error and realisation parts of `uncertainties`
    camera: dict | None = None  # a photo target's fitted gains and white balance with their σ (camera.report)
    goodness: Goodness | None = None  # the measure of fit at the result (goodness.py); None when not estimated
    failures: list = field(default_factory=list)  # why the fit failed (verdict.py); empty when it did not
    arrangement: dict | None = None  # how the strands lie, estimated at the fit's end (arrangement.py `record`)

    @property
    def failed(self) -> bool:
        return bool(self.failures)


@dataclass(frozen=True)
class Descent:
    """What the Adam iterations leave: the estimate (the mean of the last AVERAGED_FRACTION of the iterates),
    their history, how many ran and why they stopped."""

    estimate: dict
    history: History
    iterations: int
    stop_reason: str


@dataclass(frozen=True)
class Evaluation:
    """The fitted renders, one per target image, the mean image loss at them and the loss linearised there
    (what the uncertainties come from). `interrupted`: Ctrl-C stopped the fit at some stage; the images are then
    the linearisation's."""

    images: list
    loss: float
    linearization: Linearization
    interrupted: bool = False


def spp_at(iteration: int, iters: int, spp: int) -> int:
    for fraction, divisor in SPP_STAGES:
        if iteration < fraction * iters:
            return max(1, spp // divisor)
    return spp


def lr_factor(iteration: int, iters: int) -> float:
    """1 for the first 60% of the iterations, then a cosine down to FINAL_LR_FRACTION at the last."""
    half = int(CONSTANT_LR_FRACTION * iters)
    if iteration < half:
        return 1.0
    t = (iteration - half) / max(iters - 1 - half, 1)
    return FINAL_LR_FRACTION + (1 - FINAL_LR_FRACTION) * 0.5 * (1 + math.cos(math.pi * min(t, 1.0)))


def iteration_seed(seed: int, iteration: int, image: int) -> int:
    """A fresh, reproducible seed per (fit seed, iteration, image)."""
    return int(np.random.SeedSequence([seed, iteration, image]).generate_state(1)[0])


def check_settings(target: Target, settings: FitSettings) -> tuple:
    names = parse_control_names(settings.controls, target.hair.colour_input)
    check_device(settings.device)
    if settings.loss not in LOSSES:
        raise ValueError(f"unknown loss {settings.loss!r}; allowed: {list(LOSSES)}")
    for key, minimum in (
        ("iters", 1),
        ("spp", 1),
        ("patience", 1),
        ("pool", 1),
        ("batch", 1),
        ("realisation_samples", 2),
    ):
        value = getattr(settings, key)
        if key == "batch" and value is None:
            continue
        if not isinstance(value, int) or value < minimum:
            raise ValueError(f"{key} must be an integer >= {minimum}, got {value!r}")
    if not (isinstance(settings.lr, (int, float)) and math.isfinite(settings.lr) and settings.lr > 0):
        raise ValueError(f"lr must be a positive number, got {settings.lr!r}")
    if settings.refine is not None:
        if not isinstance(settings.refine, int) or settings.refine < 0:
            raise ValueError(f"refine must be an integer >= 0, got {settings.refine!r}")
        if settings.refine > 0 and settings.loss not in REFINABLE_LOSSES:
            raise ValueError(
                f"refine: Gauss–Newton steps need a sum-of-squares loss ({', '.join(REFINABLE_LOSSES)}), "
                f"not {settings.loss!r}; use refine=0 (--refine 0) with it"
            )
    check_model_error(settings.model_error)
    if settings.realisations is not None:
        check_mode(settings.realisations)
    Nuisance(target).check(names)
    unknown = sorted(set(settings.init) - set(names))
    if unknown:
        raise ValueError(
            f"init gives control(s) {unknown} that are not fitted (fitted: {list(names)}); the scene files set the "
            f"others"
        )
    return names


def start_values(names, settings: FitSettings) -> dict:
    values = {}
    for name in names:
        spec = SPECS[name]
        values[name] = as_values(name, settings.init.get(name, spec.neutral))
        spec.check_start(values[name], "init")
    return values


def _as_control(name, values):
    return values if SPECS[name].size == 3 else values[0]


class _Latents:
    """The optimiser's parameters: one latent tensor per fitted control, float64, on the render device (so that
    the renders of `render_torch_pair` come back there).

    The albedo's latent depends on β_n (latents.py): the fitted β_n's current value, else the scenes' own; and
    on the scenes' albedo inversion coefficients.
    """

    def __init__(self, start: dict, fixed_beta_n: float, inversion, device: torch.device):
        self.fixed_beta_n = float(effective_beta(fixed_beta_n))
        self.inversion = inversion
        kind = {"dtype": torch.float64, "device": device}
        beta_n = torch.tensor(start["beta_n"][0] if "beta_n" in start else self.fixed_beta_n, **kind)
        self.tensors = {
            name: SPECS[name]
            .to_latent(torch.tensor(v if SPECS[name].size == 3 else v[0], **kind), beta_n, inversion)
            .requires_grad_()
            for name, v in start.items()
        }

    def values(self) -> dict:
        beta_n = self.fixed_beta_n
        if "beta_n" in self.tensors:
            beta_n = SPECS["beta_n"].from_latent(self.tensors["beta_n"], None)
        return {name: SPECS[name].from_latent(z, beta_n, self.inversion) for name, z in self.tensors.items()}


def _plain(values: dict) -> dict:
    return {name: (v.detach().tolist() if v.dim() else float(v.detach())) for name, v in values.items()}


def _mean_values(history_values: dict, window: int) -> dict:
    return {
        name: _as_control(name, np.atleast_1d(np.mean(np.asarray(vals[-window:], dtype=np.float64), axis=0)).tolist())
        for name, vals in history_values.items()
    }


class Batches:
    """Random mini-batches of one target image's pooled blocks, for the iterations of a fit.

    An image of more than `batch` counted pixels is rendered, each iteration, on a uniformly drawn set of its
    k×k loss blocks (k = the loss's pool) that add up to about `batch` pixels; the loss over those blocks,
    divided by the whole image's scale (`losses.loss_scale`), is an unbiased estimate of the whole image's, and
    so is its gradient: a stochastic optimiser's mini-batch. The pixels of a block are rendered as they come
    out in the whole image (one random stream per pixel), so a batch changes what is rendered, not how.
    """

    def __init__(self, image, pool: int, batch: int | None):
        height, width = image.image.shape[:2]
        counted = np.ones((height, width), bool) if image.mask is None else image.mask > 0
        rows, cols = np.nonzero(counted)
        block = (rows // pool) * (-(-width // pool)) + cols // pool
        self.blocks, inverse = np.unique(block, return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        self.pixels_of = np.split((rows * width + cols)[order], np.cumsum(np.bincount(inverse))[:-1])
        self.shape = (height, width)
        self.size = len(self.blocks) if batch is None else min(len(self.blocks), max(1, round(batch / pool**2)))

    @property
    def whole(self) -> bool:
        return self.size == len(self.blocks)

    def draw(self, seed: int):
        """(pixel indices to render or None for all, the loss's mask of them (H, W) or None)."""
        if self.whole:
            return None, None
        chosen = np.random.default_rng(seed).choice(len(self.blocks), self.size, replace=False)
        pixels = np.sort(np.concatenate([self.pixels_of[b] for b in chosen]))
        mask = np.zeros(self.shape[0] * self.shape[1], bool)
        mask[pixels] = True
        return pixels, torch.from_numpy(mask.reshape(self.shape))


def _describe(values: dict) -> str:
    parts = []
    for name, v in values.items():
        parts.append(f"{name}=" + ("(" + ",".join(f"{c:.3f}" for c in v) + ")" if isinstance(v, list) else f"{v:.3f}"))
    return " ".join(parts)


def fit(target: Target, settings: FitSettings | None = None, progress: bool = True, **overrides) -> FitResult:
    """Fit the chosen controls of `target`; see the module docstring. Keyword overrides set FitSettings fields."""
    settings = settings or FitSettings()
    if overrides:
        unknown = sorted(set(overrides) - set(FitSettings.__dataclass_fields__))
        if unknown:
            raise TypeError(f"unknown fit setting(s) {unknown}")
        settings = FitSettings(**{**settings.__dict__, **overrides})
    return FitRun(target, settings, progress).run()


class FitRun:
    """One fit of a target, as a run: the state of the descent is held here and `step()` takes one Adam
    iteration; the stages after it each return a frozen result:

        run = FitRun(target, settings)
        descent = run.descend()                 # step() until the iterations, a plateau or Ctrl-C
        refinement = run.refine(descent)        # Gauss–Newton steps (refine.py); None when there are none
        evaluation = run.evaluate(descent, refinement)   # the final images and loss, the loss linearised there
        uncertainty, goodness, arrangement = run.uncertainty(evaluation, refinement)   # σ, χ², the strands' lie
        result = run.result(descent, refinement, evaluation, uncertainty, goodness, arrangement)   # or: run.run()
    """

    def __init__(self, target: Target, settings: FitSettings, progress: bool = True):
        self.target, self.settings, self.progress = target, settings, progress
        self.names = check_settings(target, settings)
        self.start = start_values(self.names, settings)
        # Renders, targets, losses and the Adam state on one device: per iteration only the controls (a few
        # floats, the kernels' launch arguments) and a mini-batch's pixels (indices, mask) cross to or from the host.
        self.device = check_device(settings.device)
        on_device = torch.device(wp.device_to_torch(self.device))
        self.latents = _Latents(self.start, target.hair.beta_n, target.hair.albedo_inversion, on_device)
        self.optimizer = torch.optim.Adam(self.latents.tensors.values(), lr=settings.lr)
        self.schedule = torch.optim.lr_scheduler.LambdaLR(self.optimizer, lambda it: lr_factor(it, settings.iters))
        self.targets = [torch.from_numpy(image.image).to(on_device) for image in target.images]
        self.masks = [None if im.mask is None else torch.from_numpy(im.mask).to(on_device) for im in target.images]
        self.scales = [loss_scale(t, settings.loss, m, settings.pool) for t, m in zip(self.targets, self.masks)]
        self.batches = [Batches(image, settings.pool, settings.batch) for image in target.images]
        self.nuisance = Nuisance(target)  # what the fit solves beside the look
        self.begun = time.perf_counter()
        self.camera_realisation = None  # a photo's gains' spread over the realisations, once `uncertainty` has it
        # The fibers, BVH, camera and lights of each image, built once: only the hair changes between renders.
        self.scenes = [prepare(image.scene, self.device) for image in target.images]
        self.random = (settings.realisations or target.realisations) == "random"
        self.realisations = Realisations(target, device=self.device) if self.random else None
        self.final_stage_spp = spp_at(settings.iters - 1, settings.iters, settings.spp)
        self.iteration = 0
        self.stop_reason = None  # set by step() on a plateau
        self.ema = self.best = None  # the smoothed loss, and its best at the final spp
        self.since_best = 0
        self.record = {"loss": [], "spp": [], "lr": [], "values": {name: [] for name in self.names}}

    @property
    def done(self) -> bool:
        return self.stop_reason is not None or self.iteration >= self.settings.iters

    def loss(self, values: dict, spp: int, seeds) -> torch.Tensor:
        """The mean image loss over the target's images, each rendered as a decorrelated pair of spp/2 each, on a
        mini-batch of its blocks where it is larger than settings.batch."""
        hair, gain = hair_and_gain(values)
        pairs, used = [], []
        # Over random realisations, both renders of an image from two different ones (realisations.py).
        scenes = self.realisations.pair(seeds[0]) if self.random else self.scenes
        for k, _image in enumerate(self.target.images):
            pixels, batch_mask = self.batches[k].draw(seeds[k])  # of counted pixels only: it implies the target's mask
            used.append(self.masks[k] if batch_mask is None else batch_mask.to(self.targets[k].device))
            pairs.append(
                render_torch_pair(
                    scenes[k],
                    hair,
                    spp=max(1, spp // 2),
                    seed=seeds[k],
                    threads=self.settings.threads,
                    pixels=pixels,
                )
            )
        # The gains every render is multiplied by (nuisance.py): a photo's solved for these renders, held in the
        # gradient (variable projection); else the exposure control's, whose gradient flows.
        gains, _ = self.nuisance.gains(
            gain, pairs, self.targets, used, self.settings.loss, self.settings.pool, self.scales
        )
        gains = [torch.as_tensor(g, device=self.targets[k].device) for k, g in enumerate(gains)]
        total = 0.0
        for k, pair in enumerate(pairs):
            for rendered in pair:
                total = total + image_loss(
                    rendered * gains[k],
                    self.targets[k],
                    self.settings.loss,
                    used[k],
                    self.settings.pool,
                    self.scales[k],
                )
        return total / (2 * len(self.target.images))

    def step(self) -> float:
        """One Adam iteration at the schedules' spp and learning rate, with fresh seeds; returns its loss. Sets
        `stop_reason` to "plateau" when the smoothed loss has not improved for `patience` iterations at the final
        spp."""
        settings, it = self.settings, self.iteration
        spp = spp_at(it, settings.iters, settings.spp)
        self.optimizer.zero_grad()
        values = self.latents.values()
        seeds = [iteration_seed(settings.seed, it, k) for k in range(len(self.target.images))]
        loss = self.loss(values, spp, seeds)
        loss.backward()
        value = float(loss.detach())
        self.record["loss"].append(value)
        self.record["spp"].append(spp)
        self.record["lr"].append(self.optimizer.param_groups[0]["lr"])
        for name, v in _plain(values).items():
            self.record["values"][name].append(v)
        self.optimizer.step()
        self.schedule.step()
        self.iteration += 1
        self.ema = value if self.ema is None else SMOOTHING * self.ema + (1 - SMOOTHING) * value
        if spp == self.final_stage_spp and it >= 1 and self.record["spp"][-2] == spp:
            if self.best is None or self.ema < self.best * (1 - PLATEAU_TOLERANCE):
                self.best, self.since_best = self.ema, 0
            else:
                self.since_best += 1
                if self.since_best >= settings.patience:
                    self.stop_reason = "plateau"
        return value

    def history(self) -> History:
        """The Adam iterations recorded so far."""
        r = self.record
        values = {
            name: np.array(v, dtype=np.float64).reshape((-1, 3) if SPECS[name].size == 3 else (-1,))
            for name, v in r["values"].items()
        }
        return History(
            loss=np.array(r["loss"], dtype=np.float64),
            spp=np.array(r["spp"], dtype=np.int64),
            lr=np.array(r["lr"], dtype=np.float64),
            values=values,
        )

    def descend(self) -> Descent:
        """step() until the iterations are done or the loss plateaus; Ctrl-C stops it with the estimate so far."""
        stop_reason = None
        bar = tqdm(total=self.settings.iters, desc=f"fit {self.target.name}", unit="it", disable=not self.progress)
        try:
            while not self.done:
                loss = self.step()
                bar.set_postfix_str(
                    f"loss={loss:.3g} spp={self.record['spp'][-1]} "
                    f"{_describe({n: v[-1] for n, v in self.record['values'].items()})}",
                    refresh=False,
                )
                bar.update()
        except KeyboardInterrupt:
            stop_reason = "interrupted"
        finally:
            bar.close()
        history = self.history()
        done = len(history.loss)
        if done == 0:
            estimate = {name: _as_control(name, self.start[name]) for name in self.names}
        else:
            estimate = _mean_values(history.values, max(1, int(AVERAGED_FRACTION * done)))
        return Descent(estimate, history, done, stop_reason or self.stop_reason or "iterations")

    @property
    def final_spp(self) -> int:
        return gauss_newton_spp(self.settings, self.target)

    @property
    def model_error(self) -> float:
        """The relative brightness disagreement σ counts for this target (uncertainty.target_model_error)."""
        return target_model_error(self.target, self.settings.model_error)

    def sparse_linearisation_note(self, uncertainty: Uncertainty) -> str | None:
        """A hint where a control's σ is above its acceptance bound (identify.BOUNDS) and the Gauss–Newton renders
        ran at fewer samples than FINAL_SPP_FACTOR × spp because the images hold more pixels than settings.batch
        (`gauss_newton_spp`): on a large image whose control barely changes it (a dense groom's β_n under a sky)
        their noise, not the images', can set that σ, and rendering every pixel at the full samples pins it
        better, at proportionally more time per step."""
        full = self.settings.spp * FINAL_SPP_FACTOR
        if self.final_spp >= full:
            return None
        names = list(uncertainty.uncertainties)
        sigma = np.concatenate([np.atleast_1d(uncertainty.uncertainties[name]) for name in names])
        bounds = np.concatenate([[BOUNDS.get(name, np.inf)] * SPECS[name].size for name in names])
        if not np.any(sigma > bounds):
            return None
        worst = int(np.argmax(sigma / bounds))
        pixels = max(image.image.shape[0] * image.image.shape[1] for image in self.target.images)
        return (
            f"{component_labels(names)[worst]} is uncertain by ±{sigma[worst]:.2g}, more than the "
            f"{bounds[worst]:g} within which a fit is held to it, and the Gauss-Newton steps rendered "
            f"{self.final_spp} samples per pixel, not {full}, because the images hold more pixels than --batch "
            f"{self.settings.batch}: --batch {pixels} renders every pixel at {full} (each step about "
            f"{full / self.final_spp:.0f}x slower), which pins it better where the images can "
            "(`warp-hair targets check` says how well they can)"
        )

    @property
    def final_seed(self) -> int:
        return iteration_seed(self.settings.seed, 2**31, 0)

    def refine(self, descent: Descent) -> Refinement | None:
        """Gauss–Newton steps from the descent's estimate (none after an interruption, or where `refine_steps`
        says 0). Ctrl-C keeps the last kept step."""
        steps = 0 if descent.stop_reason == "interrupted" else refine_steps(self.settings, self.target)
        if not steps:
            return None
        self.weigh_cards(descent.estimate)
        bar = tqdm(total=steps, desc="Gauss-Newton", unit="step", disable=not self.progress)
        run = None
        try:
            run = GaussNewton(
                self.target,
                descent.estimate,
                self.settings,
                self.final_spp,
                self.final_seed,
                steps,
                scenes=self.realisations.pair if self.random else self.scenes,
            )
            while not run.done:
                record = run.step()
                if bar.n >= bar.total:  # the refinement runs on while its points still move (refine.py)
                    bar.total = bar.n + 1
                bar.set_postfix_str(
                    f"loss={record.loss:.3g} {'kept' if record.accepted else 'undone'} {_describe(record.values)}",
                    refresh=False,
                )
                bar.update()
            bar.total = bar.n  # fewer steps than planned where Adam left the fit settled (refine.py)
            return run.result()
        except KeyboardInterrupt:
            if run is None:
                return Refinement(descent.estimate, None, None, (), interrupted=True)
            return Refinement(run.kept_values, None, None, tuple(run.steps), interrupted=True)
        finally:
            bar.close()

    def weigh_cards(self, values: dict) -> None:
        """A photo's grey cards weighed against its hair by their residuals' variances, from one linearisation at
        the descent's estimate (card_region.gls_weights), for the refinement and all after it. Adam solved the
        gains with each card block weighed as a hair block."""
        if not (self.nuisance.solved and any(image.card is not None for image in self.target.images)):
            return
        lin = linearize(
            self.target,
            values,
            self.settings,
            self.final_spp,
            iteration_seed(self.settings.seed, 2**31 - 1, 0),  # seeds of its own, apart from every other render's
            threads=self.settings.threads,
            scenes=self.realisations.pair(iteration_seed(self.settings.seed, 2**31 - 1, 1))
            if self.random
            else self.scenes,
        )
        weights = card_region.gls_weights(
            self.target, lin, self.settings, quantisation_variances(self.target, self.settings)
        )
        self.target = card_region.with_weights(self.target, weights)
        self.nuisance = Nuisance(self.target)

    def evaluate(self, descent: Descent, refinement: Refinement | None) -> Evaluation:
        """The final images and loss at the fitted controls, and the linearisation there (the refinement's, else
        one made now at FINAL_SPP_FACTOR × spp per render)."""
        values = descent.estimate if refinement is None else refinement.values
        interrupted = descent.stop_reason == "interrupted" or (refinement is not None and refinement.interrupted)
        lin = None if refinement is None else refinement.linearization
        if lin is None:
            lin = linearize(
                self.target,
                values,
                self.settings,
                self.final_spp,
                self.final_seed,
                threads=self.settings.threads,
                scenes=self.realisations.pair(self.final_seed) if self.random else self.scenes,
            )
        images = lin.images
        full_spp = self.settings.spp * FINAL_SPP_FACTOR
        if self.final_spp < full_spp and not interrupted:
            # The linearisations of a large image rendered few samples a pixel: a picture of the fit that a person
            # compares with the target (comparison.png) wants the full samples.
            try:
                images = _render_fitted(
                    self.scenes,
                    values,
                    full_spp,
                    self.final_seed,
                    self.settings.threads,
                    None if lin.camera is None else lin.camera.gains.per_channel,
                )
            except KeyboardInterrupt:
                interrupted = True
        losses = [
            image_loss(
                torch.from_numpy(fitted),
                torch.from_numpy(image.image),
                self.settings.loss,
                None if image.mask is None else torch.from_numpy(image.mask),
                self.settings.pool,
            )
            for fitted, image in zip(images, self.target.images)
        ]
        return Evaluation(images, float(np.mean([float(v) for v in losses])), lin, interrupted)

    def uncertainty(self, evaluation: Evaluation, refinement: Refinement | None) -> tuple:
        """(Uncertainty, Goodness, the arrangement's record or None): the uncertainties from the loss linearised at
        the result, with the refinement's Monte Carlo error; over random realisations, with the realisation term
        (realisations.py) and the noise term from a linearisation on one realisation. And the measure of fit
        there (goodness.py), whose Birge factor scales them where the images differ from the fitted look by more
        than noise; and where the target states a prior over how the strands lie, its estimate (`arrangement`)."""
        lin, mc = evaluation.linearization, None if refinement is None else refinement.mc_covariance
        model_error = self.model_error
        if not self.random:
            goodness = self.goodness(lin)
            determined, unpinned = pinned(lin)
            uncertainty = estimate_uncertainty(determined, mc, model_error, birge=goodness.birge, unpinned=unpinned)
            return uncertainty, goodness, None
        # The noise term from one realisation's linearisation; the curvature, and the shift per unit brightness
        # (which that linearisation's own two Jacobians alone make noisy), from the pooled one.
        columns = self.arrangement_columns(lin)
        term = self.realisation_term(lin, columns)
        self.camera_realisation = term.camera
        goodness = self.goodness(lin, term.variance)
        uncertainty = estimate_uncertainty(
            dataclasses.replace(term.linearization, curvature=term.pooled.curvature),
            mc,
            model_error,
            term.covariance,
            brightness_from=term.pooled,
            birge=goodness.birge,
            unpinned=term.unpinned,
        )
        return uncertainty, goodness, self.arrangement(lin, uncertainty, columns, term, goodness.birge)

    def goodness(self, lin: Linearization, draw=None) -> Goodness:
        """χ² of the final linearisation's residuals against the noise the fit expects there (goodness.py)."""
        return goodness_of_fit(
            lin, self.target, self.settings, self.final_spp, quantisation_variances(self.target, self.settings), draw
        )

    def realisation_term(self, lin: Linearization, arrangement=None) -> RealisationTerm:
        """K further realisations (after the pool's), each linearised at the fitted controls with both passes on
        it: the spread of the estimate they would give (realisations.py). `arrangement`: (middles, CRN columns) of
        `arrangement_columns`, where the target states a prior over how the strands lie: the part of the spread
        each realisation's draw of it makes is then counted from the prior (`realisation_spread`)."""
        count = self.settings.realisation_samples
        bar = tqdm(total=count, desc="realisations", unit="real", disable=not self.progress)
        linearizations = []
        try:
            for k in range(count):
                linearizations.append(
                    linearize(
                        self.target,
                        lin.values,
                        self.settings,
                        self.final_spp,
                        iteration_seed(self.settings.seed, 2**31 + 1 + k, 0),
                        threads=self.settings.threads,
                        scenes=self.realisations.term_scenes(k),
                    )
                )
                bar.update()
        finally:
            bar.close()
        control = None
        if arrangement is not None:
            prior, keys = self.target.arrangement, self.target.arrangement.continuous
            draws = np.array([[self.realisations.term_drawn(k)[key] for key in keys] for k in range(count)])
            control = (draws, arrangement[1].mean(axis=0), prior.covariance(keys))
        return realisation_term(lin, linearizations, control)

    def run(self) -> FitResult:
        """Every stage in order (see the module docstring), and the FitResult of them."""
        descent = self.descend()
        refinement = self.refine(descent)
        evaluation = self.evaluate(descent, refinement)
        uncertainty = goodness = arrangement = None
        if self.settings.uncertainty and not evaluation.interrupted:
            uncertainty, goodness, arrangement = self.uncertainty(evaluation, refinement)
        return self.result(descent, refinement, evaluation, uncertainty, goodness, arrangement)

    def arrangement_columns(self, lin: Linearization):
        """(middles (K, N), CRN columns (K, N, q)) of the arrangement's continuous keys at the fitted look
        (arrangement.py `columns`), in the linearisation's residuals (a photo's gains projected out), where the
        target states a prior over how the strands lie; None elsewhere."""
        prior = self.target.arrangement if self.random else None
        if prior is None or not prior.continuous:
            return None
        count = self.settings.realisation_samples
        bar = tqdm(total=count, desc="arrangement", unit="real", disable=not self.progress)
        try:
            middles, crn = [], []
            for k in range(count):  # one at a time, for the bar
                m, c = arrangement_columns(
                    self.target,
                    prior,
                    lin.values,
                    prior.continuous,
                    1,
                    self.final_spp,
                    iteration_seed(self.settings.seed, 2**31 + 1000 + k, 0),
                    self.settings,
                    threads=self.settings.threads,
                    gains=None if lin.camera is None else lin.camera.gains.per_channel.astype(np.float32),
                    rows=lin.residuals.shape[1],
                    card_rows=lin.card_rows,
                    first=k,
                    views=self.realisations.views,
                )
                middles.append(m[0])
                crn.append(c[0])
                bar.update()
        finally:
            bar.close()
        middles, crn = np.array(middles), np.array(crn)
        if lin.camera is not None:  # the loss minimised over a photo's gains: their columns projected out
            middles = np.stack([lin.camera.apply(m) for m in middles])
            crn = np.stack([lin.camera.apply(c) for c in crn])
        return middles, crn

    def arrangement(self, lin, uncertainty: Uncertainty, columns, term: RealisationTerm, birge: float) -> dict | None:
        """How the strands lie, estimated with the look at the fit's end (arrangement.py) from `arrangement_columns`
        (None where the target states no prior with continuous keys: then None) and the realisation term whose
        part it is; `birge` scales that part as `estimate_uncertainty` did."""
        if columns is None:
            return None
        prior, names = self.target.arrangement, list(lin.values)
        variance = np.concatenate([np.atleast_1d(uncertainty.uncertainties[name]) for name in names]) ** 2
        part = birge**2 * np.diag(term.arrangement)  # the arrangement's part of σ², as estimate_uncertainty scales it
        found = estimate_arrangement(prior, prior.continuous, lin.mean_jacobian, lin.loss_weights, *columns)
        return arrangement_record(prior, found, names, lin.values, variance, part, len(columns[0]), self.final_spp)

    def result(
        self,
        descent: Descent,
        refinement: Refinement | None,
        evaluation: Evaluation,
        uncertainty: Uncertainty | None,
        goodness: Goodness | None = None,
        arrangement: dict | None = None,
    ) -> FitResult:
        warnings = [] if refinement is None else list(refinement.warnings)
        note = interpenetration_note(self.target, self.model_error)
        if note is not None:
            warnings.append(note)
        if uncertainty is not None:
            warnings += uncertainty.warnings
            note = self.sparse_linearisation_note(uncertainty)
            if note is not None:
                warnings.append(note)
        values = descent.estimate if refinement is None else refinement.values
        camera_report = self.camera_report(evaluation, refinement)
        interrupted = evaluation.interrupted
        return FitResult(
            target=self.target.name,
            values=values,
            uncertainties=None if uncertainty is None else uncertainty.uncertainties,
            loss=evaluation.loss,
            start={name: _as_control(name, v) for name, v in self.start.items()},
            history=descent.history
            if refinement is None
            else dataclasses.replace(descent.history, refine=refinement.steps),
            iterations=descent.iterations,
            stop_reason="interrupted" if evaluation.interrupted else descent.stop_reason,
            seconds=time.perf_counter() - self.begun,
            images=evaluation.images,
            warnings=warnings,
            correlations={} if uncertainty is None else uncertainty.correlations,
            uncertainty_parts=None if uncertainty is None else uncertainty.parts,
            camera=camera_report,
            goodness=goodness,
            failures=[]
            if interrupted
            else failures(
                values,
                descent.history.loss,
                evaluation.loss,
                refinement,
                camera_report,
                goodness,
                () if uncertainty is None else uncertainty.undetermined,
            )
            + ([] if arrangement is None else arrangement["failures"]),
            arrangement=arrangement,
        )

    def camera_report(self, evaluation: Evaluation, refinement: Refinement | None) -> dict | None:
        """A photo target's gains and white balance with their σ (nuisance.py), None for other targets."""
        lin = evaluation.linearization
        mc = None if refinement is None else refinement.mc_covariance
        hair_covariance = lin.statistical_covariance + (0 if mc is None else mc)
        # With a grey card the gains take part of a brightness disagreement and follow the hair's share of it.
        shift = None if lin.camera is None or lin.camera.direct is None else brightness_sensitivity(lin)
        model_error = self.model_error
        return self.nuisance.report(
            lin.camera, hair_covariance, lin.scatter, model_error, shift, self.camera_realisation
        )


def _render_fitted(scenes, values: dict, spp: int, seed: int, threads, gains=None) -> list:
    """Forward renders (H, W, 3) of the target's prepared scenes at the fitted controls, exposure applied (or a
    photo's gains, (n, 3))."""
    hair, gain = hair_and_gain(values)
    gain = float(gain)
    return [
        (gain if gains is None else gains[k].astype(np.float32))
        * render(scene_with_controls(scene, hair), spp=spp, seed=seed + k, threads=threads)
        for k, scene in enumerate(scenes)
    ]
