"""Derivatives of a render with respect to the hair controls: per pixel, and of a scalar loss.

    jac, image, stderr = render_jacobian(scene, spp=32, seed=1)   # jac (H, W, 3, 8): ∂image[y, x, c]/∂θ_k
    g = render_grad(scene, adjoint)     # {control: ∂L/∂control}, L = Σ_pixels Σ_c adjoint[y, x, c] image[y, x, c]

`render_jacobian` launches the gradient variant of the renderer's pixel kernel (`render.make_pixel_kernel(True)`):
the same paths as `render(scene, spp, seed)`, each with its (3, 8) Jacobian, so one pass gives the image, its
standard errors and the whole Jacobian (memory: 24 floats per pixel, whatever the path depth). `render_grad`
contracts it with an adjoint; the Gauss–Newton curvature of the fit (optimize/uncertainty.py) and the
decorrelated image pairs of `warp_hair.torch.render_torch_pair` use it whole.

For a loss ℓ(image), pass adjoint = ∂ℓ/∂image (for 0.5‖image − target‖², image − target; render that primal
image with a different seed from the gradient pass, or the two estimates are correlated and the product biased).
Controls are named as in `HairParams.to_dict()`: "albedo" (3,), "sigma_a" (3,) or the scalars "eumelanin" and
"pheomelanin", then "beta_m", "beta_n", "alpha" (per degree), "eta", "r_roughness_scale". With albedo as the
colour input, ∂/∂β_n includes the chain through the albedo inversion (σ_a depends on β_n).

The estimator is detached sampling (docs/gradients.md): each path is traced as `render` traces it, its
directions, MIS weights and roulette probabilities held fixed, which is unbiased because the pdfs cancel. A
contribution C is then a product of BSDF values over its vertices, so ∂C_c/∂θ = C_c Σ_vertices ∂ log S_c/∂θ,
carried forward along the path with no tape (`render_jacobian` gives it per pixel; `render_grad` contracts it
with the adjoint). Nothing of the geometry is differentiated, and the roughness floor (β = 0.01) is a clamp: ∂/∂β
there is 0.
"""

from __future__ import annotations

import numpy as np

from ..controls import CONTROLS, named_theta
from ..scene import Scene
from .prepare import PreparedScene, scene_of
from .render import render_pixels


def render_jacobian(
    scene: Scene | PreparedScene,
    spp: int | None = None,
    seed: int | None = None,
    threads: int | None = None,
    device: str | None = None,
    pixels=None,
):
    """(jacobian (H, W, 3, 8) float32, image (H, W, 3), stderr (H, W, 3)) of `scene` at its own controls.

    `scene` is a Scene or a PreparedScene (`prepare`, built once for many renders); spp and seed default to the
    scene's [render] table; the image is `render(scene, spp, seed)`'s up to float rounding (the same paths).
    `pixels`: only these flat pixel indices, as in `render`; the others are 0.
    """
    image, stderr, jacobian = render_pixels(scene, spp, seed, threads, device, True, pixels=pixels)
    return jacobian, image, stderr


def _check_adjoint(adjoint, shape) -> np.ndarray:
    a = np.asarray(adjoint)
    if a.shape != shape:
        raise ValueError(f"adjoint must have the image's shape {shape} (H, W, 3), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"adjoint must be real numbers, got dtype {a.dtype}")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise ValueError("adjoint has NaN or infinite entries")
    return a


def named_gradients(params, g: np.ndarray) -> dict:
    """Name the 8 θ columns of g by control, as in `HairParams.to_dict()` (colour by its input's kind): floats,
    and arrays of three for RGB controls."""
    named = named_theta(params.colour_input, np.asarray(g, dtype=np.float64))
    return {name: v.copy() if CONTROLS[name].size == 3 else float(v) for name, v in named.items()}


def contract(adjoint: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """(8,) float64: Σ_pixels Σ_c adjoint[y, x, c] jacobian[y, x, c, k]."""
    return np.einsum("hwc,hwck->k", adjoint, jacobian.astype(np.float64))


def contract_crossed(adjoints, jacobians) -> np.ndarray:
    """(8,): each of two independent renders' adjoints met with the other render's Jacobian, summed. Independent
    paths on the two sides keep the product unbiased (render_torch_pair, the fit's gradients)."""
    return contract(adjoints[0], jacobians[1]) + contract(adjoints[1], jacobians[0])


def render_grad(
    scene: Scene | PreparedScene,
    adjoint,
    spp: int | None = None,
    seed: int | None = None,
    threads: int | None = None,
    device: str | None = None,
    return_image: bool = False,
):
    """{control: ∂L/∂control} for L = Σ adjoint ⊙ image, the image `render(scene, spp, seed)` would give.

    `scene` may be prepared (`prepare.prepare`). adjoint: (H, W, 3), the image's shape, finite. spp and seed
    default to the scene's [render] table. With
    `return_image`, returns (gradients, image): the image of the same paths (equal to `render`'s up to float
    rounding).
    """
    width, height = scene_of(scene).camera.resolution
    a = _check_adjoint(adjoint, (height, width, 3))
    jacobian, image, _ = render_jacobian(scene, spp=spp, seed=seed, threads=threads, device=device)
    named = named_gradients(scene_of(scene).hair, contract(a, jacobian))
    if return_image:
        return named, image
    return named
