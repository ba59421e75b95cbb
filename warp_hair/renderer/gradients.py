"""Gradients of a rendered image's scalar loss with respect to the hair controls.

    g = render_grad(scene, adjoint)     # {control: ∂L/∂control}, L = Σ_pixels Σ_c adjoint[y, x, c] image[y, x, c]

For a loss ℓ(image), pass adjoint = ∂ℓ/∂image (for 0.5‖image − target‖², image − target; render that primal
image with a different seed from the gradient pass, or the two estimates are correlated and the product biased).
Controls are named as in `HairParams.to_dict()`: "albedo" (3,), "sigma_a" (3,) or the scalars "eumelanin" and
"pheomelanin", then "beta_m", "beta_n", "alpha" (per degree), "eta", "r_roughness_scale". With albedo as the
colour input, ∂/∂β_n includes the chain through the albedo inversion (σ_a depends on β_n).

Estimator: detached sampling. Each path is traced exactly as `render` traces it (same seed, same random
streams, same directions), and the directions it samples, its MIS weights and its Russian-roulette probabilities
are held fixed: they are treated as functions of the random numbers only, not of θ. This is unbiased: the
derivative of ∫ f_θ is ∫ ∂f_θ, and the MIS weights of the strategies that can produce a given path sum to one
whatever values they are frozen at, so Σ_strategies E[w ∂f/p] = ∫ ∂f. (Roulette likewise: frozen survival
probabilities q and the 1/q factor cancel in expectation.) Every contribution C of a path — next-event estimation
at vertex k, or the environment reached by a BSDF-sampled ray — is then a product of BSDF values S over its
vertices divided by θ-independent quantities, so

    ∂C_c/∂θ_k = C_c Σ_vertices ∂ log S_c/∂θ_k,

with S at each vertex evaluated at the direction actually used there (the continuation for the vertices before,
the light direction for the NEE vertex itself). One forward pass accumulates it: a per-path running matrix
G[c, k] = Σ_previous fiber vertices ∂ log S_c(wi_j)/∂θ_k (= J[c, k]/S_c, skipped where S_c = 0, where the
contribution vanishes too), and each contribution adds Σ_c adjoint_c C_c (G[c, k] + ∂ log S_c(w_light)/∂θ_k)
/ spp to its pixel (the tracer keeps the channels apart: render_jacobian.py returns the per-pixel Jacobian and
this module contracts it with the adjoint). Memory does not grow with the path depth (no tape over the bounce loop). The BSDF Jacobian
J = ∂S/∂θ is in closed form (`bsdf_jacobian`): the map from the controls to the model's coefficients and its
derivatives are formed once per material on the host in float64 (`coefficient_derivatives`), and each vertex
differentiates the same evaluation of the lobes that gave S (bsdf_grad's wp.grad of the same model is its
independent check, tests/test_bsdf_jacobian.py). The card does not depend on θ.

The tracer is integrator.make_trace_path(True): the forward renderer's own loop, with the gradient code
compiled in under wp.static branches (the forward variant compiles them out). Per-pixel terms are summed on the host
in float64: the result depends on the seed only, not on the threads.

What the estimator does not include: derivatives through the sampling of the path (the directions are fixed,
which is what makes it a "detached" estimator, valid because the pdfs cancel), and nothing of the geometry.
The roughness floor (β = 0.01) is a clamp: ∂/∂β there is 0.
"""

from __future__ import annotations

import numpy as np

from ..controls import CONTROLS, named_theta
from .forward import PreparedScene, scene_of
from .jacobian import render_jacobian
from ..scene import Scene


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

    `scene` may be prepared (`render.prepare`). adjoint: (H, W, 3), the image's shape, finite. spp and seed
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
