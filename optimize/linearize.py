"""The fit's loss near given controls, linearised: its pooled, weighted residuals and their Jacobian.

With r the stacked residuals gain·I − T of the loss (after its k×k pooling, over the counted pixels and channels
of every image, weighted as the loss weighs them: per image by 1/sqrt(mean T²) for L2, per pixel by 1/(T + ε)
for relative L2) and A = ∂r/∂x their Jacobian by the fitted control components x, the loss is
≈ ‖r + A δx‖² / N near x. Gauss–Newton refinement (`refine.py`) and the uncertainties (`uncertainty.py`) both
start from there.

Each image is rendered twice with independent seeds by `render_jacobian` (one pass gives an image and its
per-pixel Jacobian), so the linearisation holds two independent estimates (r₁, A₁) and (r₂, A₂). Products of
a residual and a Jacobian then take them from different passes (`gradient`): from one pass, their Monte Carlo
errors would correlate and bias the product, as in the fit's own gradients. The L1 loss is treated as L2 here.

A Jacobian estimated from one render is noisy where a control's effect is faint next to the noise, and that
noise times our residuals' noise moves every Gauss–Newton step. Near a fit's end the refinement's points lie so close
together that their
Jacobians estimate the same matrix, so a linearisation may take earlier renders' Jacobians (`earlier_jacobians`), which
are
independent of its residuals: each residual pass then meets the mean of every Jacobian but its own
(docs/fitting.md measures what that does to the steps' scatter).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from warp_hair.controls import CONTROL_NAMES, columns
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.torch import default_grad_seed, scene_with_controls

from . import card_region
from .latents import EXPOSURE, hair_and_gain
from .losses import REL_EPSILON, block_mean, loss_scale
from .nuisance import Nuisance

CHANNELS = 3  # consecutive residuals of one pixel (or pooled block): R, G, B

# θ columns of render_jacobian, per hair control.
COLUMNS = {name: columns(name) for name in CONTROL_NAMES}


@dataclass
class Linearization:
    values: dict  # the controls it was taken at
    residuals: np.ndarray  # (2, N): the two passes' weighted, pooled residuals
    variances: np.ndarray  # (2, N): their Monte Carlo variances (from each pixel's own samples)
    jacobians: np.ndarray  # (2, N, p): ∂residual/∂x, x the fitted control components in order
    images: list  # per target image, the mean of its two renders (H, W, 3), gain applied
    loss_weights: np.ndarray  # (N,): the loss is Σ loss_weights · r² (a mean per image, then over the images)
    targets: np.ndarray | None = None  # (N,): the weighted, pooled target values t, r = weight · (gain·I) − t
    image_residuals: tuple | None = None  # how many of the N residuals each target image gives, in order
    earlier_jacobians: np.ndarray | None = None  # (n, N, p): of earlier, independent renders near `values`
    curvature: np.ndarray | None = None  # (p, p) Gauss–Newton matrix; default: `crossed_curvature` of all Jacobians
    scatter: float | None = None  # s² of `statistical_covariance`; default: this linearisation's `scatter_estimate`
    camera: object | None = None  # a photo's gains, projected out of residuals and Jacobian (camera.Projection)
    # (2, q): each pass's residuals' part along the gains' columns before they were projected out, in log-gains
    # (what the gains would take of them; realisations.camera_spread); None without gains.
    camera_moves: np.ndarray | None = None
    # (N,) a photo's weighted model ω G Ī, the passes' mean, before the projection: the gains' columns for a later
    # linearisation (`linearize`'s gain_columns). None for other targets.
    model: np.ndarray | None = None
    card_rows: np.ndarray | None = None  # (N,) bool: a grey card's rows (card_region.py), within their image's

    def __post_init__(self):
        if self.residuals.shape[1] % CHANNELS:
            raise ValueError(f"residuals come {CHANNELS} to a pixel, one per channel; got {self.residuals.shape[1]}")
        if self.curvature is None:
            self.curvature = crossed_curvature(self.all_jacobians, self.loss_weights)
        if self.scatter is None:
            self.scatter = self.scatter_estimate

    @property
    def loss(self) -> float:
        """The fit's loss at `values` (the mean of the two passes'), our render noise included."""
        return float(0.5 * (self.loss_weights @ (self.residuals**2).sum(axis=0)))

    @property
    def misfit(self) -> float:
        """The loss without our render noise: Σ w r₁ r₂ of independent passes is unbiased for Σ w E[r]², while
        Σ w r² adds our Monte Carlo variance, which grows with the radiance (a brighter albedo renders noisier,
        and on a noisy target that alone can outweigh a better fit)."""
        return float(self.loss_weights @ (self.residuals[0] * self.residuals[1]))

    @property
    def misfit_variance(self) -> float:
        """The variance of `misfit` from our render noise (and, over random realisations, the two passes'
        different strands): with r_i = μ + n_i, Σ w r₁ r₂ varies by Σ w² (μ² (v₁ + v₂) + v₁ v₂) (and the
        covariances of a pixel's channels, which share their paths). Σ over pixels of (Σ_c w r̄ d)², with
        d = r₁ − r₂ and r̄ the passes' mean, estimates exactly that: E[r̄² d²] = μ² · 2v + v² for equal passes.
        It is what `refine.py` compares a step's change of the misfit against."""
        w, r = self.loss_weights, self.residuals
        per_pixel = (w * r.mean(axis=0) * (r[0] - r[1])).reshape(-1, CHANNELS).sum(axis=1)
        return float(per_pixel @ per_pixel)

    @property
    def all_jacobians(self) -> np.ndarray:
        """(n, N, p): the earlier Jacobians, then the two passes'."""
        if self.earlier_jacobians is None:
            return self.jacobians
        return np.concatenate([self.earlier_jacobians, self.jacobians])

    @property
    def gradient(self) -> np.ndarray:
        """½ ∂loss/∂x = ∂(½ Σ w r²)/∂x, each pass's residual met with the mean of every Jacobian but its own pass's
        (unbiased; without earlier ones, the other pass's)."""
        return self.crossed(self.residuals)

    def _others(self) -> list:
        """Per pass, (N, p) the mean of every Jacobian but its own pass's (`all_jacobians`)."""
        jacobians = self.all_jacobians
        total, n = jacobians.sum(axis=0), len(jacobians)
        return [(total - a) / (n - 1) for a in self.jacobians]

    def crossed(self, vectors: np.ndarray) -> np.ndarray:
        """(p,): ½ Σ over the two passes of Aᵀ W v, each pass's v (2, N) met with the mean of every Jacobian but
        its own pass's: unbiased where v carries that pass's noise (its residual, its image)."""
        w = self.loss_weights
        return 0.5 * sum(other.T @ (w * v) for other, v in zip(self._others(), vectors))

    @property
    def gradient_covariance(self) -> np.ndarray:
        """(p, p): the covariance of `gradient` from our render noise, the Jacobians' included: each pass's term of
        `crossed` met with the other's, per pixel (or pooled block), Σ of d dᵀ with d the half difference of the
        two terms over the pixel's channels (the terms of one pixel are independent of every other's, and the two
        passes' alike). Beside `noise_covariance` it counts the Jacobians' noise times the residuals, which near the
        optimum of a target with any misfit or noise of its own moves the gradient as much or more (refine.py's
        settled test). The earlier Jacobians' noise, which both terms share, is left out."""
        w = self.loss_weights
        terms = [other * (w * v)[:, None] for other, v in zip(self._others(), self.residuals)]
        return _pixel_covariance(0.5 * (terms[0] - terms[1]))

    @property
    def noise_covariance(self) -> np.ndarray:
        """(p, p): the covariance of the gradient Aᵀ W r̄ from our render noise in the mean residual r̄,
        Aᵀ W C W A. A pixel's channels come from the same paths, so C is block diagonal, one 3×3 block per pixel
        (or pooled block), not diagonal: the Monte Carlo variances V alone understate this covariance (along β_m
        2-fold on fur_patch). It is estimated from the passes' half difference d = (r₁ − r₂)/2, which has r̄'s
        noise covariance and none of the target's scatter: Σ over pixels of (Σ_c w a d)(Σ_c w a d)ᵀ."""
        w, a = self.loss_weights, self.mean_jacobian
        half_difference = 0.5 * (self.residuals[0] - self.residuals[1])
        return _pixel_covariance((w * half_difference)[:, None] * a)

    @property
    def step_covariance(self) -> np.ndarray:
        """The covariance, from our render noise in the residuals, of where a Gauss–Newton step from here lands:
        H⁻¹ `noise_covariance` H⁻¹. It leaves out the Jacobian's own noise, so it is a lower bound where that
        noise is large."""
        h_inv = inverse_curvature(self.curvature)
        return h_inv @ self.noise_covariance @ h_inv

    @property
    def hair_rows(self) -> np.ndarray | slice:
        """The rows of the hair's pixels: all but a grey card's (`card_rows`)."""
        return slice(None) if self.card_rows is None else ~self.card_rows

    @property
    def scatter_estimate(self) -> float:
        """Σ w (r² − Var_MC) / (N − p): the target's own scatter around the model (its noise, any misfit), our
        render noise Var_MC removed; unbiased, and so negative at times where the target is far less noisy. Over
        the hair's rows: the scatter is compared with our render's noise, which a grey card's rows lack."""
        hair = self.hair_rows
        w, r = self.loss_weights[hair], self.mean_residual[hair]
        n, p = len(w), self.jacobians.shape[2]
        return float(w @ (r * r - self.mean_variance[hair])) / max(n - p, 1)

    @property
    def statistical_covariance(self) -> np.ndarray:
        """The covariance the target's scatter gives the fit, taken to correlate across a pixel's channels as our
        render's noise does: `step_covariance` scaled by the ratio of s² (`scatter`, no less than a tenth of the
        whole residual variance) to what s² would be were the target's scatter our own noise (`uncertainty.py`).
        Where channels are independent and equally noisy, that is the classical s² H⁻¹."""
        hair = self.hair_rows
        w, r = self.loss_weights[hair], self.mean_residual[hair]
        n, p = len(w), self.jacobians.shape[2]
        s2 = max(self.scatter, 0.1 * float(w @ (r * r)) / max(n - p, 1))
        ours = float(w @ self.mean_variance[hair]) / max(n - p, 1)
        return s2 / max(ours, 1e-300) * self.step_covariance

    @property
    def mean_residual(self) -> np.ndarray:
        return self.residuals.mean(axis=0)

    @property
    def mean_variance(self) -> np.ndarray:
        """The Monte Carlo variance of mean_residual."""
        return self.variances.sum(axis=0) / 4.0

    @property
    def mean_jacobian(self) -> np.ndarray:
        return self.all_jacobians.mean(axis=0)


def _pixel_covariance(terms: np.ndarray) -> np.ndarray:
    """(p, p): Σ over pixels (or pooled blocks) of d dᵀ, d the sum of a pixel's CHANNELS rows of `terms` (N, p):
    the covariance of Σ terms where a pixel's channels, which share their paths, move together and pixels do not."""
    per_pixel = terms.reshape(-1, CHANNELS, terms.shape[1]).sum(axis=1)
    return per_pixel.T @ per_pixel


def crossed_curvature(jacobians: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The Gauss–Newton matrix Σ w aᵢ aⱼ (½ the loss's Hessian without residual curvature) from n ≥ 2 independent
    estimates of the Jacobian, unbiased: the mean over every pair of distinct ones. A Jacobian's product with
    itself adds its own Monte Carlo variance to the diagonal, and where a column is mostly noise that dominates:
    on fur_patch it would overstate β_n's curvature up to 15-fold, making steps along β_n that much too short
    and its uncertainty that much too small. When noise leaves the crossed matrix not positive definite, the mean
    Jacobian's product with itself is used instead."""
    n = len(jacobians)
    total = jacobians.sum(axis=0)
    crossed = _crossed_mean(total, np.einsum("kni,n,knj->ij", jacobians, weights, jacobians), weights, n)
    if np.all(np.linalg.eigvalsh(crossed) > 0):
        return crossed
    a = (total / n) * np.sqrt(weights)[:, None]
    return a.T @ a


def _crossed_mean(total: np.ndarray, squares: np.ndarray, weights: np.ndarray, n: int) -> np.ndarray:
    """Σ w aᵢ aⱼ averaged over the pairs of distinct ones of n Jacobians, from their sum `total` (N, p) and the sum
    of their products with themselves `squares` (p, p); symmetric."""
    crossed = (total.T @ (weights[:, None] * total) - squares) / (n * (n - 1))
    return 0.5 * (crossed + crossed.T)


# A direction of the curvature whose crossed estimate lies less than this many of its standard errors above zero is
# not determined by the images at this noise: zero is within its 95% interval, and the Jacobians' noise, not the
# images, would set its σ. (At 3, a light swatch's red albedo, 2.9 errors up, lost a σ that covered its errors.)
DETERMINED_Z = 2.0


def curvature_directions(jacobians: np.ndarray, weights: np.ndarray) -> tuple:
    """(values (p,), vectors (p, p) as columns, standard errors (p,)): the eigen-directions of the crossed curvature
    (`crossed_curvature`'s unbiased mean over distinct pairs, before any fallback) and the jackknife standard error of
    each value over the n ≥ 3 Jacobians (each left out in turn, the crossed mean of the rest along the same direction).
    Where a control's column is mostly noise (β_n of an opaque swatch averaged over many arrangements), its direction's
    value is zero within its error, or below: the product fallback would count the noise as curvature."""
    n = len(jacobians)
    if n < 3:
        raise ValueError(f"the curvature's standard errors need at least 3 Jacobians, got {n}")
    total = jacobians.sum(axis=0)
    squares = np.einsum("kni,n,knj->kij", jacobians, weights, jacobians)
    all_squares = squares.sum(axis=0)
    values, vectors = np.linalg.eigh(_crossed_mean(total, all_squares, weights, n))
    along = np.einsum("nk,kp->np", total, vectors)  # the total's projection on each direction (N, p)
    left_out = []
    for j in range(n):
        rest = along - jacobians[j] @ vectors
        own = np.einsum("ip,ij,jp->p", vectors, all_squares - squares[j], vectors)
        left_out.append((np.einsum("np,n,np->p", rest, weights, rest) - own) / ((n - 1) * (n - 2)))
    left_out = np.array(left_out)
    errors = np.sqrt((n - 1) / n * ((left_out - left_out.mean(axis=0)) ** 2).sum(axis=0))
    return values, vectors, errors


def inverse_curvature(curvature: np.ndarray) -> np.ndarray:
    """The curvature's (pseudo-)inverse: a curvature restricted to the directions the images determine
    (uncertainty.py `pinned`) is singular by construction, and its zero directions must stay zero, not become the
    inverse of rounding."""
    return np.linalg.pinv(curvature, rcond=1e-10)


def linearize(
    target, values: dict, settings, spp: int, seed: int, threads=None, scenes=None, gain_columns=None
) -> Linearization:
    """Render every image of `target` twice at `values` (spp each) and linearise the loss there.

    `scenes`: the target's scenes prepared once (`warp_hair.prepare`, one per image, in order), so that
    repeated linearisations do not rebuild the BVH; by default each image's scene, prepared here once for both
    passes. An image's entry may be a pair of scenes, one per pass: two realisations of its fibers' recipe
    (optimize/realisations.py). `gain_columns`: a photo's weighted model (`Linearization.model`) of an earlier,
    independent linearisation near `values`, whose render gives the gains' columns instead of the target
    (`nuisance.Nuisance.projection` says when and why)."""
    hair, gain = hair_and_gain(values)
    scenes = [prepare(image.scene) for image in target.images] if scenes is None else scenes
    renders = []  # per image, its two passes' (Jacobian, image, standard error)
    for k in range(len(target.images)):
        pair = scenes[k] if isinstance(scenes[k], tuple) else (scenes[k], scenes[k])
        renders.append(
            [
                render_jacobian(scene_with_controls(scene, hair), spp=spp, seed=pass_seed, threads=threads)
                for scene, pass_seed in zip(pair, (seed + k, default_grad_seed(seed + k)))
            ]
        )
    # The gains every render is multiplied by (nuisance.py): a photo's solved for these renders, else exposure's.
    pairs = [(p[0][1], p[1][1]) for p in renders]
    masks = [None if image.mask is None else torch.from_numpy(image.mask) for image in target.images]
    references = [torch.from_numpy(image.image) for image in target.images]
    scales = [loss_scale(t, settings.loss, m, settings.pool) for t, m in zip(references, masks)]
    nuisance = Nuisance(target)
    per_image, solved = nuisance.gains(float(gain), pairs, references, masks, settings.loss, settings.pool, scales)
    gains = np.stack([np.broadcast_to(np.asarray(g, dtype=np.float64), (3,)) for g in per_image])
    rs, vs, js = [[], []], [[], []], [[], []]
    images, weights, ts, on_card, counts = [], [], [], [], []
    for k, image in enumerate(target.images):
        reference, _ = pool_like_loss(image, image.image, None, settings.pool)
        weight = loss_weights(reference, settings.loss)
        ts.append(reference * weight)
        on_card.append(np.zeros(reference.size, bool))
        counts.append(reference.size)
        pair = []
        g = gains[k].astype(np.float32)
        for half, (jac, raw, stderr) in enumerate(renders[k]):
            rendered = g * raw
            # r = weight · (gain·I − T): ∂r/∂gain = weight · I, ∂r/∂θ = weight · gain · ∂I/∂θ.
            columns = [raw[..., None] if name == EXPOSURE else g[:, None] * jac[..., COLUMNS[name]] for name in values]
            a, _ = pool_like_loss(image, np.concatenate(columns, axis=-1).astype(np.float64), None, settings.pool)
            r, var = pool_like_loss(image, rendered - image.image, (g * stderr) ** 2, settings.pool)
            rs[half].append(r * weight)
            vs[half].append(var * weight**2)
            js[half].append(a * weight[:, None])
            pair.append(rendered)
        images.append(0.5 * (pair[0] + pair[1]))
        weights.append(np.full(reference.size, 1.0 / (reference.size * len(target.images))))
        if getattr(image, "card", None) is not None and solved is not None:
            # A grey card's rows (card_region.py), weighed against the image's hair rows by their variances
            # (`card_region.gls_weights`): no render, no noise of ours, no hair in them.
            card_r, card_t = card_region.rows(image, gains[k], reference, settings.loss, settings.pool)
            for half in range(2):
                rs[half].append(card_r)
                vs[half].append(np.zeros(card_r.size))
                js[half].append(np.zeros((card_r.size, js[half][-1].shape[1])))
            ts.append(card_t)
            on_card.append(np.ones(card_r.size, bool))
            weights.append(np.full(card_r.size, weights[-1][0] * image.card.weight))
            counts[-1] += card_r.size
    residuals = np.stack([np.concatenate(r) for r in rs])
    jacobians = np.stack([np.concatenate(j) for j in js])
    targets = np.concatenate(ts)
    weights = np.concatenate(weights)
    on_card = np.concatenate(on_card)
    card_rows = on_card if on_card.any() else None
    image_residuals = tuple(counts)
    projection = nuisance.projection(solved, targets, weights, jacobians, image_residuals, gain_columns)
    model = camera_moves = None
    if projection is not None:
        model = residuals.mean(axis=0) + targets
        if card_rows is not None:
            # A brightness disagreement of our render scales the hair's rows, not the card's, whose radiance is
            # known (uncertainty.brightness_sensitivity takes `targets` as what it scales).
            targets = np.where(card_rows, 0.0, targets)
            projection.direct = np.linalg.pinv(projection.normal) @ (projection.columns.T @ (weights * targets))
        camera_moves = np.stack([projection.coefficients(r) for r in residuals])
        residuals = np.stack([projection.apply(r) for r in residuals])
        jacobians = np.stack([projection.apply(a) for a in jacobians])
        targets = projection.apply(targets)
    return Linearization(
        values=dict(values),
        residuals=residuals,
        variances=np.stack([np.concatenate(v) for v in vs]),
        jacobians=jacobians,
        images=images,
        loss_weights=weights,
        targets=targets,
        image_residuals=image_residuals,
        camera=projection,
        camera_moves=camera_moves,
        card_rows=card_rows,
        model=model,
    )


def loss_weights(reference: np.ndarray, loss: str) -> np.ndarray:
    """Per pooled residual, the loss's weight (losses.py): 1/sqrt(mean T²) for L2 and L1, 1/(T + ε mean T) for
    relative L2, T the pooled target."""
    if loss == "rel_l2":
        return 1.0 / (reference + REL_EPSILON * reference.mean())
    return np.full(reference.shape, 1.0 / max(float(np.sqrt(np.mean(reference * reference))), 1e-15))


def _pooled(x: np.ndarray, weight: np.ndarray, pool: int) -> tuple:
    """Block means of (H, W, ...) over k×k blocks with pixel weights, flattened; and the blocks' weight sums."""
    shape = x.shape
    flat = torch.from_numpy(np.ascontiguousarray(x.reshape(shape[0], shape[1], -1), dtype=np.float64))
    means, totals = block_mean(flat, torch.from_numpy(weight.astype(np.float64)), pool)
    return means.numpy(), totals.numpy()


def pool_like_loss(image, x, var, pool):
    """Pool (H, W, ...) like the loss does (masked pixels left out) and flatten; var is pooled as a variance."""
    weight = np.ones(x.shape[:2]) if image.mask is None else image.mask.astype(np.float64)
    if pool > 1:
        means, totals = _pooled(x, weight, pool)
        keep = totals > 0
        out = means[keep].reshape(-1, *x.shape[3:]) if x.ndim > 3 else means[keep].reshape(-1)
        if var is None:
            return out, None
        # The variance of a block mean of independent pixels: Σ var / n².
        v, _ = _pooled(var, weight, pool)
        return out, (v[keep] / totals[keep][:, None]).reshape(-1)
    keep = weight > 0
    out = x[keep].reshape(-1, *x.shape[3:]) if x.ndim > 3 else x[keep].reshape(-1)
    return out, None if var is None else var[keep].reshape(-1)
