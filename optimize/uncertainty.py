"""Uncertainties of the fitted controls from the curvature of the loss at the estimate, and identifiability.

With r the stacked residuals gain·I − T of the loss (after its k×k pooling, over the counted pixels and
channels of every image) and A = ∂r/∂x its Jacobian with respect to the fitted control components x (per-pixel
derivatives of the renders from `render_jacobian`, pooled the same way), the loss is ≈ ‖r + A δx‖² / N near x.

Uncertainty (the classical standard errors of nonlinear least squares):

    Cov(x) ≈ s² (AᵀA)⁻¹,     s² = (Σ r² − Σ Var_MC) / (N − p),

where Var_MC is the Monte Carlo variance of our own render of the residual (its per-pixel standard errors),
removed so that s² measures what the target scatters by around the model (its own noise and any misfit), not
the noise of our evaluation. r and A are weighted as the loss weighs them: per image by 1/sqrt(mean T²) for L2,
per pixel by 1/(T + ε) for relative L2; the L1 loss is treated as L2 here.

Identifiability: two components whose estimates correlate by |ρ| > 0.95 trade off against each other in these
images (albedo and β_n can, through the albedo inversion, under a single front light); a control the images do
not change with has a zero column in A. Both end in `result.warnings` with what to do about them.
"""

from __future__ import annotations

import itertools

import numpy as np
import torch

from warp_hair.render import render
from warp_hair.render_jacobian import render_jacobian
from warp_hair.torch import scene_with_controls

from .controls import EXPOSURE, SPECS
from .losses import REL_EPSILON, block_mean

CORRELATION_WARNING = 0.95
# θ columns of render_jacobian (warp_hair.bsdf_grad's ordering).
COLUMNS = {"beta_m": [3], "beta_n": [4], "alpha": [5], "eta": [6], "r_roughness_scale": [7],
           "albedo": [0, 1, 2], "sigma_a": [0, 1, 2], "eumelanin": [0], "pheomelanin": [1]}


def component_labels(names) -> list[str]:
    labels = []
    for name in names:
        labels += [f"{name}[{'rgb'[k]}]" for k in range(3)] if SPECS[name].size == 3 else [name]
    return labels


def _pooled(x: np.ndarray, weight: np.ndarray, pool: int) -> tuple:
    """Block means of (H, W, ...) over k×k blocks with pixel weights, flattened; and the blocks' weight sums."""
    shape = x.shape
    flat = torch.from_numpy(np.ascontiguousarray(x.reshape(shape[0], shape[1], -1), dtype=np.float64))
    means, totals = block_mean(flat, torch.from_numpy(weight.astype(np.float64)), pool)
    return means.numpy(), totals.numpy()


def _hair(values: dict) -> dict:
    return {name: v for name, v in values.items() if name != EXPOSURE}


def residuals(target, values: dict, settings, spp: int, seed: int) -> tuple:
    """(r (N,), Monte Carlo variance of r (N,)) of the loss's pooled residuals from one render per image."""
    gain = float(values.get(EXPOSURE, 1.0))
    rs, vs = [], []
    for k, image in enumerate(target.images):
        rendered, stderr = render(scene_with_controls(image.scene, _hair(values)), spp=spp, seed=seed + k,
                                  threads=settings.threads, return_stderr=True)
        r, var = _weighted(image, gain * rendered - image.image, (gain * stderr) ** 2, settings)
        r, var = _reduce(image, r, var, settings.pool)
        rs.append(r)
        vs.append(var)
    return np.concatenate(rs), np.concatenate(vs)


def jacobian(target, values: dict, settings, spp: int, seed: int) -> np.ndarray:
    """A (N, p): ∂ of the pooled residuals (as `residuals` orders them) by each fitted control component."""
    names = list(values)
    gain = float(values.get(EXPOSURE, 1.0))
    blocks = []
    for k, image in enumerate(target.images):
        jac, rendered, _ = render_jacobian(scene_with_controls(image.scene, _hair(values)), spp=spp, seed=seed + k,
                                           threads=settings.threads)
        columns = [rendered[..., None] if name == EXPOSURE else gain * jac[..., COLUMNS[name]] for name in names]
        a = np.concatenate(columns, axis=-1)  # (H, W, 3, p)
        a = a * (_rel_weight(image)[..., None] if settings.loss == "rel_l2" else _image_scale(image, settings.pool))
        blocks.append(_reduce(image, a, None, settings.pool)[0].reshape(-1, a.shape[-1]))
    return np.concatenate(blocks)


def _rel_weight(image) -> np.ndarray:
    return 1.0 / (image.image + REL_EPSILON * image.image.mean())


def _image_scale(image, pool) -> float:
    """1 / sqrt(mean T²) over the values the loss compares: L2's per-image normalisation (losses.py)."""
    t, _ = _reduce(image, image.image, None, pool)
    return 1.0 / max(float(np.sqrt(np.mean(t * t))), 1e-15)


def _weighted(image, r, var, settings):
    if settings.loss == "rel_l2":
        w = _rel_weight(image)
        return r * w, var * w * w
    w = _image_scale(image, settings.pool)
    return r * w, var * w * w


def _reduce(image, x, var, pool):
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


def gauss_newton(target, result, settings, spp: int, seed: int) -> None:
    """Fill result.uncertainties, result.correlations and identifiability warnings (see the module docstring)."""
    names = list(result.values)
    A = jacobian(target, result.values, settings, spp, seed)
    r, mc_variance = residuals(target, result.values, settings, spp, seed + 50)
    n, p = A.shape
    labels = component_labels(names)
    flat = np.abs(A).max(axis=0) == 0
    for label in np.array(labels)[flat]:
        result.warnings.append(f"{label} does not change the rendered images at all: it cannot be fitted from this target")
    s2 = max(float(r @ r - mc_variance.sum()), 0.1 * float(r @ r)) / max(n - p, 1)
    cov = s2 * np.linalg.pinv(A.T @ A)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    result.uncertainties = _by_control(names, sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cov / np.outer(sigma, sigma)
    owners = [label.split("[")[0] for label in labels]
    for i, j in itertools.combinations(range(p), 2):
        if owners[i] == owners[j] or not np.isfinite(rho[i, j]):
            continue
        result.correlations[f"{labels[i]}/{labels[j]}"] = float(rho[i, j])
        if abs(rho[i, j]) > CORRELATION_WARNING:
            result.warnings.append(
                f"{labels[i]} and {labels[j]} are not separately identifiable from these images (correlation "
                f"{rho[i, j]:+.3f}): a change of one is compensated by the other. Add an image under another light "
                "(a back-lit one shows transmission) or fix one of them."
            )


def _by_control(names, flat) -> dict:
    out, k = {}, 0
    for name in names:
        size = SPECS[name].size
        out[name] = [float(v) for v in flat[k:k + size]] if size == 3 else float(flat[k])
        k += size
    return out
