"""Per-pixel derivatives of a render with respect to the hair controls: ∂image[y, x, c]/∂θ_k.

    jac, image, stderr = render_jacobian(scene, spp=32, seed=1)   # jac (H, W, 3, 8), θ as in bsdf_grad

`render_grad` returns Σ_pixels adjoint · ∂image/∂θ; with the adjoint e_c at every pixel, its per-pixel terms are
row c of each pixel's Jacobian. Three gradient passes (one per channel, the same seed, so the same paths) give
the whole Jacobian: what Gauss–Newton curvature needs (optimize/uncertainty.py). The image and its per-pixel
standard errors come from a forward render of those same paths.
"""

from __future__ import annotations

import numpy as np

from .render import render
from .render_grad import per_pixel_gradients
from .scene import Scene


def render_jacobian(scene: Scene, spp: int | None = None, seed: int | None = None, threads: int | None = None):
    """(jacobian (H, W, 3, 8) float64, image (H, W, 3), stderr (H, W, 3)) of `scene` at its own controls."""
    width, height = scene.camera.resolution
    rows = []
    for c in range(3):
        adjoint = np.zeros((height, width, 3), dtype=np.float32)
        adjoint[..., c] = 1.0
        rows.append(per_pixel_gradients(scene, adjoint, spp=spp, seed=seed, threads=threads))
    image, stderr = render(scene, spp=spp, seed=seed, threads=threads, return_stderr=True)
    return np.stack(rows, axis=2), image, stderr
