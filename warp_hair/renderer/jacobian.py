"""Per-pixel derivatives of a render with respect to the hair controls, ∂image[y, x, c]/∂θ_k, in one pass.

    jac, image, stderr = render_jacobian(scene, spp=32, seed=1)   # jac (H, W, 3, 8)

The gradient variant of the renderer's pixel kernel (`forward.make_render_kernel(True)`) traces the same paths as
`render(scene, spp, seed)` and returns each path's radiance with its (3, 8) Jacobian (docs/gradients.md): one
pass gives the image, its standard errors and the whole Jacobian. `render_grad` contracts it with an adjoint;
the Gauss–Newton curvature of the fit (optimize/uncertainty.py) and the decorrelated image pairs of
`warp_hair.torch.render_torch_pair` use it whole. Memory: 24 floats per pixel, whatever the path depth.
"""

from __future__ import annotations

from ..scene import Scene
from .forward import trace_pixels
from .prepare import PreparedScene


def render_jacobian(scene: Scene | PreparedScene, spp: int | None = None, seed: int | None = None,
                    threads: int | None = None, device: str | None = None, pixels=None):
    """(jacobian (H, W, 3, 8) float32, image (H, W, 3), stderr (H, W, 3)) of `scene` at its own controls.

    `scene` is a Scene or a PreparedScene (`prepare`, built once for many renders); spp and seed default to the
    scene's [render] table; the image is `render(scene, spp, seed)`'s up to float rounding (the same paths).
    `pixels`: only these flat pixel indices, as in `render`; the others are 0.
    """
    image, stderr, jacobian = trace_pixels(scene, spp, seed, threads, device, True, pixels=pixels)
    return jacobian, image, stderr
