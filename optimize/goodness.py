"""How well the fitted look describes the images: χ² per view and in total, against what noise alone predicts.

At the estimate, each pooled, weighted residual r̄ (the mean of the final linearisation's two passes) should
differ from zero by noise alone, if the model describes the images:

    E[r̄²] ≈ σ²_ours + σ²_target + σ²_draw + σ²_code

- σ²_ours: our two renders' Monte Carlo variance of their mean, from each pixel's own samples;
- σ²_target: the target's own Monte Carlo noise where it is a render (a scene's [render] spp says how many samples
  it had): our per-sample variance scaled to its samples (`identify.py` takes the target's noise the same way);
- σ²_draw: over random realisations, how far the target's strands, one draw of the recipe, and our two
  renders' draws differ (1.5 × one realisation's variance per residual, from the realisation term's
  cross-pass variances);
- σ²_code: a photo's quantisation (`quantisation_variances`). A photo's own noise (sensor, JPEG's
  compression) is not known and counts as misfit: χ² of a photo is a bound from above.

The measure is the ratio of the residuals' energy to what noise alone gives them,

    χ²/dof = Σ r̄² / (Σ E[r̄²] · (N − p)/N),

p fitted components taking their share out as in s² = Σ r²/(N − p): 1 where the model describes the images to
their noise. (The classical Σ r̄²/E[r̄²] weighs each residual by its own noise, and a render's per-pixel
variance from its own samples is far too small on the dim pixels whose rare bright paths it has not yet
drawn: on black_straight at its truth that sum came out 57 per degree of freedom in the front view, this
ratio 0.94.) Its spread under noise alone is √(2 · 3 · Σ E²)/Σ E (Gaussian residuals, a pixel's three
channels counted as moving together), and it is significant beyond SIGNIFICANCE of those. The Particle Data
Group's rule (Review of Particle Physics, "Introduction", §5.2, averaging inconsistent measurements) scales the
uncertainties by S = √(χ²/dof) where that is significantly above 1 (`birge`). Within a view, the region with
the largest excess energy Σ r̄² − Σ E[r̄²] among the brightness thirds of its blocks (the highlight, the mid
tones, the dark fibers), a 3 × 3 grid of the frame and a grey card says where the images are not described.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from warp_hair.photo import srgb_decode

from . import camera, card_region
from .linearize import CHANNELS, Linearization, loss_weights, pool_like_loss

# χ²/dof above 1 by more than this many of its standard deviations (√(2/dof), times the channels' share of
# paths: a pixel's three residuals move together) is beyond noise.
SIGNIFICANCE = 5.0
GRID = ("top", "middle", "bottom"), ("left", "centre", "right")
BRIGHTNESS = ("the darkest third of its blocks", "its mid-tone third", "its brightest third (the highlight)")


@dataclass(frozen=True)
class ViewFit:
    """One target image's χ², its degrees of freedom and the region that fits worst."""

    name: str
    chi2: float
    dof: float
    region: str
    region_ratio: float  # that region's χ²/dof
    spread: float = 0.0  # the standard deviation of this view's χ²/dof under noise alone

    @property
    def ratio(self) -> float:
        return self.chi2 / max(self.dof, 1e-300)

    @property
    def significant(self) -> bool:
        """Whether this view's χ²/dof is above 1 by more than noise would put it (as `Goodness.significant`)."""
        return self.ratio > 1.0 + SIGNIFICANCE * self.spread


@dataclass(frozen=True)
class Goodness:
    """The measure of fit (module docstring): per view and in total; `counted` names the noises counted."""

    views: tuple[ViewFit, ...]
    chi2: float
    dof: float
    counted: tuple[str, ...]
    photo: bool  # a photo's own noise is not counted: χ²/dof is a bound from above
    spread: float = 0.0  # the standard deviation of χ²/dof under noise alone (module docstring)

    @property
    def ratio(self) -> float:
        return self.chi2 / max(self.dof, 1e-300)

    @property
    def significant(self) -> bool:
        """Whether χ²/dof is above 1 by more than noise in χ² itself would put it (SIGNIFICANCE × `spread`)."""
        return self.ratio > 1.0 + SIGNIFICANCE * self.spread

    @property
    def birge(self) -> float:
        """S = √(χ²/dof) where that is significantly above 1, else 1: the factor on the uncertainties."""
        return float(np.sqrt(self.ratio)) if self.significant else 1.0

    def worst_view(self) -> ViewFit:
        return max(self.views, key=lambda v: v.ratio)

    def to_dict(self) -> dict:
        return {
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_per_dof": self.ratio,
            "birge_factor": self.birge,
            "counted": list(self.counted),
            "photo_noise_counted": not self.photo,
            "views": {
                v.name: {
                    "chi2": v.chi2,
                    "dof": v.dof,
                    "chi2_per_dof": v.ratio,
                    "worst_region": v.region,
                    "worst_region_chi2_per_dof": v.region_ratio,
                }
                for v in self.views
            },
        }

    def lines(self) -> list[str]:
        """The printed account: the total, each view, where it fits worst."""
        note = " (the photo's own noise, sensor and compression, is not known: counted as misfit)" if self.photo else ""
        out = [f"goodness of fit: chi2/dof {self.ratio:.2f} over {self.dof:.0f} degrees of freedom{note}"]
        for v in self.views:
            out.append(f"  {v.name}: chi2/dof {v.ratio:.2f}; worst in {v.region} ({v.region_ratio:.2f})")
        if self.significant:
            out.append(
                f"  the images differ from the fitted look by more than noise: uncertainties scaled by "
                f"S = sqrt(chi2/dof) = {self.birge:.2f}"
            )
        return out


def expected_variance(
    lin: Linearization, lin_spp: int, target_spp: list, quantisation=None, draw=None
) -> tuple[np.ndarray, tuple]:
    """(N,) E[r̄²] per residual under the noise model (module docstring), and the names of what it counts.
    lin_spp: samples per pixel of each of lin's passes; target_spp: per image, its samples (None: not a render,
    a photo); quantisation, draw: (N,) or None."""
    per_sample = lin.variances.mean(axis=0) * lin_spp  # one sample's variance, per residual
    expected = lin.mean_variance.copy()
    counted = ["our renders' Monte Carlo noise"]
    start, renders = 0, False
    for count, spp in zip(lin.image_residuals, target_spp):
        if spp:
            expected[start : start + count] += per_sample[start : start + count] / spp
            renders = True
        start += count
    if renders:
        counted.append("the target's Monte Carlo noise (its [render] spp)")
    if quantisation is not None:
        expected += quantisation
        counted.append("the photo's quantisation")
    if draw is not None:
        expected += 1.5 * np.maximum(draw, 0.0)
        counted.append("the strands' draw (realisations)")
    return expected, tuple(counted)


def goodness_of_fit(lin: Linearization, target, settings, lin_spp: int, quantisation=None, draw=None) -> Goodness:
    """The measure of fit of the linearisation's mean residuals at the estimate (module docstring); `settings`
    the fit's (its pooling), lin_spp the samples per pass of lin's renders."""
    photo = any(image.from_photo for image in target.images)
    target_spp = [None if image.photo is not None else image.scene.render.spp for image in target.images]
    expected, counted = expected_variance(lin, lin_spp, target_spp, quantisation, draw)
    r2 = lin.mean_residual**2
    p = lin.jacobians.shape[2]
    counts = lin.image_residuals
    n_total = sum(counts)
    views, start = [], 0
    for image, count in zip(target.images, counts):
        part = slice(start, start + count)
        views.append(_view(image, r2[part], expected[part], p * count / n_total, settings.pool))
        start += count
    dof = n_total - p
    chi2 = dof * _ratio(r2, expected, p)
    spread = float(np.sqrt(2.0 * CHANNELS * (expected**2).sum()) / max(expected.sum(), 1e-300))
    return Goodness(tuple(views), float(chi2), float(dof), counted, photo, spread)


def _ratio(r2: np.ndarray, expected: np.ndarray, fitted: float) -> float:
    """Σ r̄² over Σ E[r̄²], with the share of the residuals' energy that the p fitted components take out
    (p/N of it, as in s² = Σ r²/(N − p))."""
    n = len(r2)
    return float(r2.sum() / max(expected.sum() * (n - fitted) / max(n, 1), 1e-300))


def _view(image, r2: np.ndarray, expected: np.ndarray, fitted: float, pool: int) -> ViewFit:
    """A view's measure of fit and its worst region: the brightness thirds of its hair blocks and a 3 × 3 grid of
    the frame, each judged by its excess residual energy Σ r̄² − Σ E[r̄²]."""
    h, w = image.image.shape[:2]
    yy, xx = np.meshgrid(np.arange(h, dtype=np.float64) / h, np.arange(w, dtype=np.float64) / w, indexing="ij")
    position, _ = pool_like_loss(image, np.stack([yy, xx], axis=-1), None, pool)
    position = position.reshape(-1, 2)  # per pooled block
    hair = CHANNELS * len(position)  # the hair's rows come first; a grey card's follow (linearize.py)
    brightness, _ = pool_like_loss(image, image.image.astype(np.float64), None, pool)
    regions = {}
    if hair:
        level = brightness.reshape(-1, CHANNELS).mean(axis=1)
        which = np.searchsorted(np.quantile(level, [1 / 3, 2 / 3]), level)
        for k, label in enumerate(BRIGHTNESS):
            regions[label] = np.repeat(which == k, CHANNELS)
        row = np.minimum((position[:, 0] * 3).astype(int), 2)
        col = np.minimum((position[:, 1] * 3).astype(int), 2)
        for i, vertical in enumerate(GRID[0]):
            for j, horizontal in enumerate(GRID[1]):
                regions[f"the frame's {vertical} {horizontal}"] = np.repeat((row == i) & (col == j), CHANNELS)
    if len(r2) > hair:
        regions["the grey card"] = np.arange(len(r2)) >= hair
    best, best_excess, best_ratio = "no region in particular", -np.inf, 1.0
    for label, members in regions.items():
        members = np.pad(members, (0, len(r2) - len(members)))
        if members.sum() < 3 * CHANNELS:
            continue
        excess = float(r2[members].sum() - expected[members].sum())
        if excess > best_excess:
            best, best_excess = label, excess
            best_ratio = _ratio(r2[members], expected[members], fitted * members.sum() / len(r2))
    dof = len(r2) - fitted
    spread = float(np.sqrt(2.0 * CHANNELS * (expected**2).sum()) / max(expected.sum(), 1e-300))
    return ViewFit(image.name, dof * _ratio(r2, expected, fitted), float(dof), best, float(best_ratio), spread)


def quantisation_variances(target, settings) -> np.ndarray | None:
    """(N,): the variance a photo's code values add to each weighted, pooled residual: a code is the value
    rounded to 1/(2^bits − 1) of the range, an error uniform over one step (variance step²/12), times the
    transfer curve's slope there, over the photo pixels `targets photo` averaged into each pixel
    (`TargetImage.coding`; independent roundings). JPEG's compression error comes on top of that and is not
    counted here (the fit's own σ, from its residuals' scatter, counts it). None when no image is coded."""
    if all(image.coding is None for image in target.images):
        return None
    parts = []
    for image in target.images:
        reference, _ = pool_like_loss(image, image.image, None, settings.pool)
        weight = loss_weights(reference, settings.loss)
        coding = image.coding
        if coding is None or coding[0] == 32:
            parts.append(np.zeros(reference.size))
            if image.card is not None and camera.fitted(target):
                parts.append(np.zeros(card_region.card_values(image, settings.pool).size))
            continue
        bits, transfer, averaged = coding
        step = 1.0 / (2**bits - 1)
        linear = image.image.astype(np.float64)
        if transfer == "linear":
            slope = np.ones_like(linear)
        else:  # the decoded value's change per code, by a finite step of the curve (sRGB or a power law)
            encoded = np.clip(np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055), 0, 1)
            slope = (srgb_decode(np.minimum(encoded + step, 1.0)) - linear) / step
        variance = (slope * step) ** 2 / 12.0 / averaged
        _, pooled = pool_like_loss(image, np.zeros_like(linear), variance, settings.pool)
        parts.append(pooled * weight**2)
        if image.card is not None and camera.fitted(target):  # its rows follow the image's (linearize.py)
            parts.append(card_quantisation(image, reference, variance, settings))
    return np.concatenate(parts)


def card_quantisation(image, reference, variance, settings) -> np.ndarray:
    """A grey card's rows of `_quantisation_variances`: its pixels' quantisation variance pooled over its blocks,
    times its rows' ω² (card_region.rows)."""
    pooled = card_region.card_variances(image, variance, settings.pool)
    values = card_region.card_values(image, settings.pool)
    return (pooled * card_region.omega(values, reference, settings.loss) ** 2).reshape(-1)
