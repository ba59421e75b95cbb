"""A photograph's exposure and white balance: unknowns fitted jointly with the hair, by variable projection.

A photo target's image k, channel c, is the scene's radiance times a gain the camera chose,

    T_kc ≈ G_kc · I_kc(θ),     G_kc = g_k · w_c,     w_G = 1,

g_k the exposure of view k (auto exposure, a bracket) and w the white balance, one per channel with green's
pinned (a common factor on w is the same as one on every g_k). `Target.gains` says which are unknown:

    per-image   a g_k per image (the default for display-referred images: PNG, JPEG, TIFF)
    exif        one g, times each image's EXIF exposure t·ISO/N² relative to the first's
    shared      one g for every image (the `exposure` control, fitted in closed form)
    none        G = 1 on every image's gains (EXR rendered at a known light level)

and `Target.white_balance` ("fit" or "none") whether w is. The gains enter linearly, so for given renders the
loss's best gains have a closed form, and the fit never steps them: each loss evaluation solves them from the
renders it has (`solve`: alternating least squares on the bilinear g·w, from per-image, per-channel sums), the
hair's gradient is taken with them held (at their optimum the loss does not change with them, so that is the
gradient of the loss minimised over the gains: Golub & Pereyra 1973, "variable projection"), and the
linearisation projects their columns out of its residuals and Jacobian (`project`): Gauss–Newton steps and the
hair's uncertainties are then those of the loss minimised over the gains, which counts every trade-off between a
gain and a hair control (the Schur complement of the joint curvature).

What the images can tell apart: a gain on every pixel of an image and a brighter albedo differ in where they
brighten. The primary highlight R is reflected at the cuticle, so it has the light's colour whatever the fiber's
absorption; TT, TRT and the multiply scattered light are filtered by the fiber. A per-channel w brightens both
alike, and in every view alike; albedo_c only the second, and the back-lit view's transmission more than the
front-lit view's glow: that pins w (within 0.4% on the photo-like swatches, light hair too). The overall level
is what the gains take: in light hair, which scatters most of its light, a lighter albedo and a brighter gain
change the images almost alike (`warp-hair targets check` says by how much). A grey card pins both: its
radiance is its reflectance times the light's, with no hair in it. Modelled in the scene (a `[card]` the camera
sees) it is rendered like the hair; marked in the photo by a mask (card_region.py) its radiance is known without
rendering, and its pixels add terms to `solve`'s sums and rows to the linearisation, with no hair in them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from . import card_region
from .losses import REL_EPSILON, _pool

GAIN_MODES = ("per-image", "exif", "shared", "none")
WHITE_BALANCE_MODES = ("fit", "none")
ALS_ITERATIONS = 60
GREEN = 1


@dataclass
class Gains:
    """Per image (n, 3) gains G_kc = g_k w_c, and the parts: g (n,), w (3,)."""

    g: np.ndarray
    w: np.ndarray

    @property
    def per_channel(self) -> np.ndarray:
        return self.g[:, None] * self.w[None, :]


def fitted(target) -> bool:
    """Whether the target's gains or white balance are unknowns of the fit."""
    return getattr(target, "gains", "none") != "none" or getattr(target, "white_balance", "none") != "none"


def relative_exposures(target) -> np.ndarray:
    """Per image, the exposure the gain is tied to: EXIF's t·ISO/N² over the first image's ("exif"), else 1."""
    if target.gains != "exif":
        return np.ones(len(target.images))
    values = np.array([image.relative_exposure for image in target.images], dtype=np.float64)
    return values / values[0]


def solve(a: np.ndarray, b: np.ndarray, target) -> Gains:
    """The gains minimising Σ_kc (b_kc G_kc² − 2 a_kc G_kc), the loss's part that depends on them, with
    a_kc = Σ ω² I T and b_kc = Σ ω² I² over image k's counted (pooled) pixels of channel c, each image's weight ω²
    included. Alternating least squares on g and w (each step exact; the loss falls at every step)."""
    n = a.shape[0]
    ratios = relative_exposures(target)
    g, w = np.ones(n), np.ones(3)
    fit_w = target.white_balance == "fit"
    b = np.maximum(b, 1e-300)
    for _ in range(ALS_ITERATIONS if fit_w else 1):
        if target.gains == "per-image":
            g = (a @ w) / np.maximum(b @ (w * w), 1e-300)
        elif target.gains in ("exif", "shared"):
            scale = float(ratios @ (a @ w)) / max(float((ratios**2) @ (b @ (w * w))), 1e-300)
            g = scale * ratios
        if fit_w:
            w = (g @ a) / np.maximum((g * g) @ b, 1e-300)
            if target.gains != "none":
                g = g * w[GREEN]
                w = w / w[GREEN]
    g = np.where(np.isfinite(g) & (g > 0), g, 1.0)
    w = np.where(np.isfinite(w) & (w > 0), w, 1.0)
    return Gains(g, w)


def loss_sums(pairs, targets, masks, loss: str, pool: int, scales) -> tuple:
    """(a, b), each (n, 3), of the loss's image terms (see `solve`), from two independent renders of each image
    (torch or NumPy (H, W, 3); their values only). a takes their mean; b = Σ ω² I₁ I₂ takes one from each, as the
    loss's gradients do (linearize.py): Σ ω² Ī² would add the renders' own noise variance, which grows the lower
    the samples, and the gains would shrink by it (g = a / b), leaving every render too dim for the target and
    the hair drifting brighter from iteration to iteration to make up for it."""
    a, b = np.zeros((len(pairs), 3)), np.zeros((len(pairs), 3))
    for k, (pair, target, mask, scale) in enumerate(zip(pairs, targets, masks, scales)):
        reference, counted = _pool(torch.as_tensor(target).to(torch.float64), mask, pool)
        pooled = []
        for image in pair:
            x, _ = _pool(torch.as_tensor(image).detach().to(torch.float64), mask, pool)
            pooled.append((x if counted is None else x[counted]).reshape(-1, 3))
        reference = (reference if counted is None else reference[counted]).reshape(-1, 3)
        if loss == "rel_l2":
            weight = 1.0 / (reference + REL_EPSILON * float(scale)) ** 2
        else:
            weight = torch.full_like(reference, 1.0 / max(float(scale), 1e-30))
        weight = weight / (reference.shape[0] * len(pairs))
        # Three numbers each to the host, where the gains are solved (the renders may be on a GPU).
        a[k] = (weight * 0.5 * (pooled[0] + pooled[1]) * reference).sum(0).cpu().numpy()
        b[k] = (weight * pooled[0] * pooled[1]).sum(0).cpu().numpy()
    return a, b


def gains_for(target, pairs, targets, masks, loss: str, pool: int, scales) -> Gains:
    """The best gains for these renders: per image, two independent renders of it (`loss_sums`), and a grey
    card's pixels where an image has one marked (card_region.py: its terms need no render)."""
    a, b = loss_sums(pairs, targets, masks, loss, pool, scales)
    card = card_region.sums(target, loss, pool, scales)
    if card is not None:
        a, b = a + card[0], b + card[1]
    return solve(a, b, target)


# -- The linearisation: project the gains' columns out (linearize.py calls these). -------------------------------


def columns(target, m: np.ndarray, image_residuals) -> np.ndarray:
    """(N, q): ∂r/∂(log gain, log w_R, log w_B) = the weighted render m = ω G I (N,) in the residuals each scales:
    a gain its image's (or every image's), w_c its channel's. linearize.py passes the weighted target (which m
    equals at the gains' optimum up to the residual), or in a refinement's later steps the mean of earlier
    renders (`nuisance.Nuisance.projection` says why)."""
    n_res = len(m)
    starts = np.cumsum((0, *tuple(image_residuals)))
    cols = []
    if target.gains == "per-image":
        for k in range(len(image_residuals)):
            col = np.zeros(n_res)
            col[starts[k] : starts[k + 1]] = m[starts[k] : starts[k + 1]]
            cols.append(col)
    elif target.gains in ("exif", "shared"):
        cols.append(m.copy())
    if target.white_balance == "fit":
        channel = np.arange(n_res) % 3
        for c in (0, 2) if target.gains != "none" else (0, 1, 2):
            cols.append(np.where(channel == c, m, 0.0))
    return np.stack(cols, axis=1)


def labels(target) -> list:
    names = []
    if target.gains == "per-image":
        names += [f"gain[{image.name}]" for image in target.images]
    elif target.gains in ("exif", "shared"):
        names.append("gain")
    if target.white_balance == "fit":
        names += (
            ["white_balance[r]", "white_balance[b]"]
            if target.gains != "none"
            else [f"white_balance[{c}]" for c in "rgb"]
        )
    return names


def label_values(projection, target) -> list:
    """The values of `labels(target)`, in order: each view's gain (or the one gain), then the white balance."""
    names = [image.name for image in target.images]
    values = []
    for label in projection.labels:
        inside = label[label.find("[") + 1 : -1] if "[" in label else None
        if label.startswith("gain"):
            values.append(float(projection.gains.g[names.index(inside) if inside else 0]))
        else:
            values.append(float(projection.gains.w["rgb".index(inside)]))
    return values


@dataclass
class Projection:
    """The gains' columns C (N, q) and what projecting them out needs, kept for their uncertainties."""

    gains: Gains
    columns: np.ndarray
    weights: np.ndarray  # (N,) the loss weights W
    jacobian: np.ndarray  # (N, p) the hair's mean Jacobian before projection
    labels: list
    # (q,) with a grey card (card_region.py): how far the log-gains move per unit brightness disagreement of the
    # hair's render, (CᵀWC)⁻¹CᵀW t with t the weighted target on the hair's rows only (the card's radiance is
    # known, not rendered). None without one: then the gains absorb the disagreement whole (1 on each gain).
    direct: np.ndarray | None = None

    @property
    def normal(self) -> np.ndarray:
        return self.columns.T @ (self.weights[:, None] * self.columns)

    def coefficients(self, x: np.ndarray) -> np.ndarray:
        """(Cᵀ W C)⁻¹ Cᵀ W x, along the first axis of x (N, ...): x's part along the gains' columns, in log-gains."""
        flat = x.reshape(x.shape[0], -1)
        return (np.linalg.pinv(self.normal) @ (self.columns.T @ (self.weights[:, None] * flat))).reshape(
            (self.columns.shape[1], *x.shape[1:])
        )

    def apply(self, x: np.ndarray) -> np.ndarray:
        """P⊥ x = x − C (Cᵀ W C)⁻¹ Cᵀ W x, along the first axis of x (N, ...): the part no change of the gains
        makes."""
        shape = x.shape
        flat = x.reshape(shape[0], -1)
        return (flat - self.columns @ self.coefficients(flat)).reshape(shape)

    @property
    def follow(self) -> np.ndarray:
        """(q, p): how the log-gains follow the hair, −(CᵀWC)⁻¹CᵀWA per unit of each control component."""
        return -np.linalg.pinv(self.normal) @ (self.columns.T @ (self.weights[:, None] * self.jacobian))

    def brightness(self, shift: np.ndarray | None = None) -> np.ndarray:
        """(q,): the log-gains' move per unit brightness disagreement ε. Without a card every gain takes it whole
        (and the white balance none); with one, `direct` plus the gains' following the hair's own move (`shift`,
        (p,) per unit ε, uncertainty.brightness_sensitivity)."""
        if self.direct is None:
            return np.array([label.startswith("gain") for label in self.labels], dtype=float)
        return self.direct + (0.0 if shift is None else self.follow @ shift)

    def covariance(
        self, hair_covariance: np.ndarray, scatter: float, model_error: float, shift: np.ndarray | None = None
    ) -> np.ndarray:
        """(q, q) of the log-gains: the hair's uncertainty carried over (`follow`), the target's scatter
        s² (CᵀWC)⁻¹ on the gains themselves, and a brightness disagreement ε moving them by ε `brightness`."""
        inverse = np.linalg.pinv(self.normal)
        follow = self.follow
        cov = follow @ hair_covariance @ follow.T + max(scatter, 0.0) * inverse
        moved = self.brightness(shift)
        return cov + model_error**2 * np.outer(moved, moved)


def report(
    projection: Projection,
    target,
    hair_covariance: np.ndarray,
    scatter: float,
    model_error: float,
    shift: np.ndarray | None = None,
    realisation: np.ndarray | None = None,
) -> dict:
    """{"gains": {image name: [value, σ]}, "white_balance": {"value": [r, g, b], "sigma": [...]}, "modes": ...},
    σ from the log-gains' covariance (σ of a gain = gain · σ of its log); `shift` the hair's move per unit
    brightness disagreement (used with a grey card, `Projection.brightness`); `realisation` (q, q) the log-gains'
    spread over the target's strand realisations (realisations.camera_spread), added."""
    cov = projection.covariance(hair_covariance, scatter, model_error, shift)
    if realisation is not None:
        cov = cov + realisation
    sigma = dict(zip(projection.labels, np.sqrt(np.maximum(np.diag(cov), 0.0))))
    g, w = projection.gains.g, projection.gains.w
    gains = {}
    for k, image in enumerate(target.images):
        s = sigma.get(f"gain[{image.name}]", sigma.get("gain", 0.0))
        gains[image.name] = [float(g[k]), float(g[k] * s)]
    wb_sigma = [float(w[c] * sigma.get(f"white_balance[{'rgb'[c]}]", 0.0)) for c in range(3)]
    # Each card's block's weight against a hair block (card_region.gls_weights), per image with a card.
    card_weights = {im.name: float(im.card.weight) for im in target.images if getattr(im, "card", None) is not None}
    return {
        "modes": {"gains": target.gains, "white_balance": target.white_balance},
        "cards": list(card_weights),
        "card_weights": card_weights,
        "gains": gains,
        "white_balance": {"value": [float(v) for v in w], "sigma": wb_sigma},
    }
