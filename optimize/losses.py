"""Image losses on linear radiance, with an optional mask of the pixels that count.

    l2      mean (I − T)² / mean T²             the default: unbiased with decorrelated gradient passes
    rel_l2  mean (I − T)² / (T + ε)²            dark and bright pixels weigh alike; ε = 1% of the target's mean
    l1      mean |I − T| / mean T               robust to a few outlier pixels

All are means over the unmasked pixels and the three channels, and L2 and L1 are divided by the target's own
scale, so losses of differently sized and differently bright images add up on one scale. That matters for a
target's joint fit: a back-lit swatch can be ten times brighter than the front-lit one, and unnormalised its
noise would drown the signal of the front image, which carries the colour. The mask (H, W) of booleans marks the pixels
that count (e.g. the fibers, not the background).

`pool` k > 1 compares the images averaged over k×k blocks (masked pixels left out of the averages): the loss
then measures appearance at the scale of a few fibers rather than per pixel. Why it matters: a target rendered
with a delta light is noisiest exactly at the fibers' highlight pixels, which are also the pixels most
sensitive to the roughnesses, so per-pixel L2 lets the fit explain the target's own noise with wrong
roughnesses. Averaging within blocks cancels that noise before it is compared.
"""

from __future__ import annotations

import torch

LOSSES = ("l2", "rel_l2", "l1")
REL_EPSILON = 0.01


def block_mean(image: torch.Tensor, weight: torch.Tensor, pool: int):
    """(H, W, C) → per k×k block Σ weight·image / Σ weight, and the blocks' total weights (partial edge blocks kept)."""
    summed = torch.nn.functional.avg_pool2d(
        (image * weight[..., None]).permute(2, 0, 1)[None], pool, ceil_mode=True, divisor_override=1
    )
    total = torch.nn.functional.avg_pool2d(weight[None, None], pool, ceil_mode=True, divisor_override=1)
    return (summed / total.clamp_min(1e-12))[0].permute(1, 2, 0), total[0, 0]


def _pool(x: torch.Tensor, mask, pool: int):
    """x over k×k blocks (masked pixels left out), and the mask of the blocks (or pixels) that count."""
    if pool == 1:
        return x, mask
    weight = torch.ones(x.shape[:2], dtype=x.dtype, device=x.device) if mask is None else mask.to(x.dtype)
    means, total = block_mean(x, weight, pool)
    return means, total > 0


def _scale(counted_target: torch.Tensor, kind: str) -> torch.Tensor:
    return (counted_target * counted_target).mean() if kind == "l2" else counted_target.abs().mean()


def loss_scale(target: torch.Tensor, kind: str = "l2", mask: torch.Tensor | None = None, pool: int = 1) -> torch.Tensor:
    """The target's own scale that `image_loss` divides by (mean T² for L2, mean |T| for L1, the mean T of
    relative L2's ε), over the counted (pooled) pixels."""
    pooled, counted = _pool(target, mask, pool)
    return _scale(pooled if counted is None else pooled[counted], kind)


def image_loss(
    image: torch.Tensor,
    target: torch.Tensor,
    kind: str = "l2",
    mask: torch.Tensor | None = None,
    pool: int = 1,
    scale: torch.Tensor | None = None,
):
    """The loss of `image` against `target` over the pixels `mask` counts. `scale`: the target's scale to divide
    by (`loss_scale`), by default its own under `mask`; a mini-batch of blocks passes the whole image's, so that
    its loss is an unbiased estimate of the whole image's rather than a ratio of two estimates."""
    if kind not in LOSSES:
        raise ValueError(f"unknown loss {kind!r}; allowed: {list(LOSSES)}")
    image, counted = _pool(image, mask, pool)
    target, _ = _pool(target.to(image.dtype), mask, pool)
    if counted is not None:
        image, target = image[counted], target[counted]
    scale = _scale(target, kind) if scale is None else scale.to(image.dtype)
    diff = image - target
    if kind == "l2":
        return (diff * diff).mean() / scale.clamp_min(1e-30)
    if kind == "l1":
        return diff.abs().mean() / scale.clamp_min(1e-30)
    return ((diff / (target + REL_EPSILON * scale)) ** 2).mean()
