"""A grey card in a photo, marked by a mask: it pins the photo's gains and white balance without rendering.

A photographer puts a grey card of known reflectance in the shot. Nobody modelled it in the scene (that is a
`[card]`, which warp-hair renders), so target.toml names, per image, a mask of its pixels, and says what it is:

    [card]                          # the target's card (or per image: card = {reflectance = ..., normal = ...})
    reflectance = 0.18              # or [r, g, b] from the card's datasheet, each in (0, 1]
    normal = "camera"               # facing the camera; or [x, y, z] in scene coordinates

    [[images]]
    scene = "scene_front.toml"
    image = "front.jpg"
    card_mask = "front_card.png"    # white (> half) = the card; those pixels are not hair

Its radiance is known without rendering: L_c = ρ_c/π · E_c, the irradiance the scene's lights give it
(`warp_hair.grey_card`). Each card pixel then says T_kc ≈ G_kc · L_c, linear in the gain G_kc = g_k w_c and free
of the hair, so its terms join the loss the gains are solved from (camera.py): per image k and channel c,

    a_kc += Σ ω² L_c T_c,    b_kc += Σ ω² L_c²,

over the card's pooled blocks, ω² the loss's weight and each block counted as one of the image's hair blocks
is (the hair's terms are means over its N_k counted blocks, so the card's are sums divided by N_k). In the
linearisation the card adds rows ω (G L − T) with no hair Jacobian; projecting the gains' columns out of them
(camera.Projection) then counts the card's information on the gains, and through them on the hair.

What is assumed and checked: the card is flat, Lambertian and unshadowed (its shadow, and light the hair throws
onto it, are not modelled: mask an open part of it, facing the lights); the scene's lights are the shoot's. A
card pixel that is clipped or crushed in the photo is left out (counted in `CardRegion.note`); a card with none
left, a card the lights do not reach in some channel, are errors.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from warp_hair import validate
from warp_hair.grey_card import card_normal, card_radiance

from .losses import REL_EPSILON, block_mean

CARD_KEYS = ("reflectance", "normal")


@dataclass
class CardRegion:
    """One image's grey card: the pixels that count (True), its reflectance, unit normal and radiance (3,)."""

    mask: np.ndarray  # (H, W) bool: the card's pixels that count (clipped and crushed ones left out)
    marked: np.ndarray  # (H, W) bool: every pixel the mask marks (none of them is hair)
    reflectance: np.ndarray
    normal: np.ndarray
    radiance: np.ndarray  # ρ/π · E, per channel, in the scene's light units
    note: str = ""
    # What each of its blocks weighs against one of the image's hair blocks: 1 until the fit measures both
    # (`gls_weights`), after its descent.
    weight: float = 1.0


def description(table, where: str) -> dict:
    """A card table ({reflectance, normal}), checked: reflectance a number or [r, g, b] in (0, 1], normal
    "camera" or [x, y, z]. Returns {"reflectance": (3,) float64, "normal": "camera" or (3,) float64}."""
    if not isinstance(table, dict):
        raise ValueError(f"{where}: must be a table with reflectance = ... and normal = ...")
    unknown = sorted(set(table) - set(CARD_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {list(CARD_KEYS)}")
    missing = [key for key in CARD_KEYS if key not in table]
    if missing:
        raise ValueError(
            f'{where}: needs {" and ".join(missing)} (reflectance = 0.18 or [r, g, b] in (0, 1]; normal = "camera" '
            "or [x, y, z] in scene coordinates)"
        )
    value = table["reflectance"]
    values = value if isinstance(value, list) else [value]
    if len(values) not in (1, 3) or not all(validate.is_number(v) for v in values):
        raise ValueError(f"{where}: reflectance = {value!r}; allowed: a number or [r, g, b], each in (0, 1]")
    rho = np.broadcast_to(np.array(values, dtype=np.float64), (3,)).copy()
    if not (np.isfinite(rho).all() and (rho > 0).all() and (rho <= 1).all()):
        raise ValueError(f"{where}: reflectance = {value!r}; each value must lie in (0, 1] (an 18% grey card: 0.18)")
    normal = table["normal"]
    if not (normal == "camera" or isinstance(normal, list)):
        raise ValueError(f'{where}: normal = {normal!r}; allowed: "camera" or [x, y, z] in scene coordinates')
    return {"reflectance": rho, "normal": normal}


def region(marked: np.ndarray, card: dict, scene, image: np.ndarray, photo, where: str) -> CardRegion:
    """The card of one image: `marked` its mask's pixels, `card` its `description`, in `scene`'s lights; the
    photo's clipped and crushed pixels left out (an error when none is left)."""
    normal = card_normal(scene, card["normal"], f"{where}: normal")
    radiance = card_radiance(scene, card["reflectance"], normal)
    if not (radiance > 0).all():
        dark = ", ".join("RGB"[c] for c in range(3) if radiance[c] <= 0)
        shown = (normal.round(4) + 0.0).tolist()
        raise ValueError(
            f"{where}: the scene's lights give the card (normal {shown}) no light in {dark}: it cannot pin the "
            "gains there; check its normal (it must face a light) or leave its mask out of this image"
        )
    counted, note = marked, ""
    if photo is not None:
        clipped, crushed = marked & photo.clipped, marked & photo.crushed & ~photo.clipped
        counted = marked & ~(clipped | crushed)
        if not counted.any():
            raise ValueError(
                f"{where}: every one of the card's {int(marked.sum())} pixels is clipped ({int(clipped.sum())}) or "
                f"crushed ({int(crushed.sum())}): nothing of it is left to pin the gains; expose so that the "
                "card lies within the range"
            )
        if clipped.any() or crushed.any():
            note = (
                f"card: {int(clipped.sum())} clipped and {int(crushed.sum())} crushed of its {int(marked.sum())} "
                "pixels left out"
            )
    if not (image[counted] > 0).any():
        raise ValueError(f"{where}: the card's pixels are black in the image: it cannot pin the gains")
    return CardRegion(counted, marked, card["reflectance"], normal, radiance, note)


def _pooled(image_values: np.ndarray, mask: np.ndarray, pool: int) -> tuple:
    """((M, 3) float64, (M,) pixel counts): `image_values` (H, W, 3) over the mask's pixels, pooled over k×k
    blocks as the loss pools (losses.block_mean; blocks holding no masked pixel dropped)."""
    values = torch.from_numpy(np.ascontiguousarray(image_values, dtype=np.float64))
    if pool == 1:
        picked = values[torch.from_numpy(mask)].numpy()
        return picked, np.ones(len(picked))
    means, totals = block_mean(values, torch.from_numpy(mask.astype(np.float64)), pool)
    keep = totals > 0
    return means[keep].numpy(), totals[keep].numpy()


def card_variances(image, variance: np.ndarray, pool: int) -> np.ndarray:
    """(M, 3): per-pixel variances (H, W, 3) over the card's counted pixels, as the variance of each block's mean
    (Σ var / n², the pixels independent)."""
    means, counts = _pooled(variance, image.card.mask, pool)
    return means / counts[:, None]


def hair_blocks(image, pool: int) -> int:
    """How many pooled blocks (or pixels) of the image's hair the loss counts: what a card block counts as one of."""
    mask = np.ones(image.image.shape[:2], bool) if image.mask is None else image.mask
    return len(_pooled(np.zeros((*mask.shape, 3)), mask, pool)[0])


def card_values(image, pool: int) -> np.ndarray:
    """(M, 3): the photo's pooled values over the card's counted pixels."""
    return _pooled(image.image, image.card.mask, pool)[0]


def weights(card: np.ndarray, loss: str, scale: float) -> np.ndarray:
    """(M, 3) ω² of the card's blocks, as the loss weighs a hair block of the same target value (`camera.loss_sums`,
    `linearize.loss_weights`): 1/scale for L2 (and L1, taken as L2), 1/(T + ε scale)² for relative L2."""
    if loss == "rel_l2":
        return 1.0 / (card + REL_EPSILON * float(scale)) ** 2
    return np.full(card.shape, 1.0 / max(float(scale), 1e-30))


def sums(target, loss: str, pool: int, scales) -> tuple | None:
    """(a, b), each (n, 3): the cards' terms of `camera.solve`'s sums, in `camera.loss_sums`' units; None where no
    image has a card."""
    if not any(getattr(image, "card", None) is not None for image in target.images):
        return None
    n = len(target.images)
    a, b = np.zeros((n, 3)), np.zeros((n, 3))
    for k, (image, scale) in enumerate(zip(target.images, scales)):
        if image.card is None:
            continue
        values = card_values(image, pool)
        w = image.card.weight * weights(values, loss, float(scale)) / (hair_blocks(image, pool) * n)
        radiance = image.card.radiance[None, :]
        a[k] = (w * radiance * values).sum(axis=0)
        b[k] = (w * radiance * radiance).sum(axis=0)
    return a, b


def omega(values: np.ndarray, reference: np.ndarray, loss: str) -> np.ndarray:
    """(M, 3) ω of the card's blocks (their values `values`) in the linearisation, as `linearize.loss_weights`
    weighs the image's pooled hair values `reference`: 1/sqrt(mean T²) for L2 (and L1), 1/(T + ε mean T) for
    relative L2, T the card's own value."""
    if loss == "rel_l2":
        return 1.0 / (values + REL_EPSILON * float(reference.mean()))
    return np.full(values.shape, 1.0 / max(float(np.sqrt(np.mean(reference * reference))), 1e-15))


def rows(image, gains: np.ndarray, reference: np.ndarray, loss: str, pool: int) -> tuple:
    """The card's rows of the linearisation (flattened R, G, B per block): (residuals ω (G L − T), weighted targets
    ω T), ω from the image's pooled hair values `reference` (`omega`)."""
    values = card_values(image, pool)
    w = omega(values, reference, loss)
    model = gains[None, :] * image.card.radiance[None, :]
    return (w * (model - values)).reshape(-1), (w * values).reshape(-1)


# A card's block is never taken as more exact than this fraction of its value: the precision of a half-float EXR
# (2⁻¹¹), which a card rendered or decoded without noise would otherwise pin the gains beyond.
CARD_PRECISION = 2.0**-11


def gls_weights(target, lin, settings, quantisation) -> list:
    """Per target image, its card's weight against a hair block (1 without a card): the hair's residual variance
    per row over the card's own, as generalised least squares weighs rows by their inverse variance, and never less
    than 1. A hair row's residual holds the photo's noise and whatever the scene does not describe (the strands'
    draw, the recipe); a card's only the photo's noise and the card's own unevenness, for its radiance is known
    (ρ/π · E). Weighed alike (1), a card of a hundred pixels was outweighed by the hair and the gains ran off along
    their valley with the albedo (docs/acceptance.md). The hair's variance is its rows' scatter about the model with
    our render's noise taken out (as `Linearization.scatter_estimate`; it is counted apart, and the gains' σ, s²
    (CᵀWC)⁻¹ in camera.Projection, then holds the card's own variance), per row of `lin` at the descent's estimate;
    the card's the largest of its blocks' scatter about their mean, CARD_PRECISION and, for a photo, its codes'
    rounding taken as one error for the whole card (`quantisation`, goodness.quantisation_variances, or None), per
    row in the same weighted units."""
    out, start = [], 0
    for image, count in zip(target.images, lin.image_residuals):
        rows = slice(start, start + count)
        start += count
        if getattr(image, "card", None) is None:
            out.append(1.0)
            continue
        values = card_values(image, settings.pool)
        m = values.size
        hair = lin.mean_residual[rows][: count - m]
        hair_variance = float(np.mean(hair * hair - lin.mean_variance[rows][: count - m]))
        reference, _ = _hair_reference(image, settings.pool)
        omega2 = omega(values, reference, settings.loss) ** 2
        scatter = values.var(axis=0, ddof=1) if len(values) > 1 else np.zeros(3)
        card = np.maximum(scatter[None, :], (CARD_PRECISION * values) ** 2) * omega2
        if quantisation is not None:
            # A flat card rounds alike throughout (no noise dithers its codes): its mean is known no better than
            # one pixel's rounding, so each of its blocks' variances is at least that many blocks times it.
            counts = _pooled(np.zeros((*image.card.mask.shape, 3)), image.card.mask, pool=settings.pool)[1]
            pixel = quantisation[rows][count - m :].reshape(-1, 3) * counts[:, None]
            card = np.maximum(card, pixel * len(counts))
        out.append(max(1.0, hair_variance / max(float(np.mean(card)), 1e-300)))
    return out


def _hair_reference(image, pool: int):
    from .linearize import pool_like_loss  # linearize imports this module

    return pool_like_loss(image, image.image, None, pool)


def with_weights(target, weights):
    """The target with each image's card weighed as `weights` says (`gls_weights`)."""
    images = [
        image if image.card is None else dataclasses.replace(image, card=dataclasses.replace(image.card, weight=w))
        for image, w in zip(target.images, weights)
    ]
    return dataclasses.replace(target, images=images)


def summary(target) -> list[str]:
    """One line per image with a card: what it is, its pixels counted, its radiance in the scene's light (what
    `warp-hair fit` and `targets check` print)."""
    lines = []
    for image in target.images:
        card = image.card
        if card is None:
            continue
        rho = "/".join(f"{v:g}" for v in card.reflectance)
        lines.append(
            f"{image.name}: grey card of reflectance {rho}, normal {(card.normal.round(3) + 0.0).tolist()}, "
            f"{int(card.mask.sum())} pixels counted, radiance {'/'.join(f'{v:.4g}' for v in card.radiance)} in "
            "the scene's light (unshadowed, as assumed)" + (f"; {card.note}" if card.note else "")
        )
    return lines
