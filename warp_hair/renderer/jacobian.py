"""Per-pixel derivatives of a render with respect to the hair controls, ∂image[y, x, c]/∂θ_k, in one pass.

    jac, image, stderr = render_jacobian(scene, spp=32, seed=1)   # jac (H, W, 3, 8), θ as in bsdf_grad

The gradient tracer (integrator.make_trace_path(True); render_grad.py explains the estimator) returns each
path's radiance and its (3, 8) Jacobian together, so one pass over the same paths as `render(scene, spp, seed)`
gives the image, its standard errors and the whole Jacobian, for what a forward render plus the derivatives
cost. `render_grad` contracts the Jacobian with an adjoint; Gauss–Newton curvature (optimize/uncertainty.py)
and the decorrelated image pairs of `warp_hair.torch.render_torch_pair` use it whole. Memory: 24 floats per
pixel, whatever the path depth.
"""

from __future__ import annotations

import warp as wp

from ..model.jacobian import CoefficientDerivatives, coefficient_derivatives, value_jacobian_mat
from .camera import generate_ray
from .integrator import SceneData, pixel_start, rand2, standard_error, trace_path_grad
from ..parallel import launch_ranges
from .forward import PreparedScene, prepare, sampling, tile_pixels
from ..scene import Scene

wp.set_module_options({"enable_backward": False, "optimization_level": 3})


@wp.kernel
def render_jacobian_kernel(
    scene: SceneData,
    derivs: CoefficientDerivatives,
    spp: int,
    seed: int,
    image: wp.array(dtype=wp.vec3),
    stderr: wp.array(dtype=wp.vec3),
    jacobian: wp.array(dtype=value_jacobian_mat),
    first: int,
):
    pixel = wp.tid() + first
    px, py, rng = pixel_start(scene, pixel, seed)
    total = wp.vec3(0.0)
    total_sq = wp.vec3(0.0)
    total_jacobian = value_jacobian_mat()
    for s in range(spp):
        jitter, rng = rand2(rng)
        origin, direction = generate_ray(scene.camera, px, py, jitter)
        radiance, path_jacobian, rng = trace_path_grad(scene, origin, direction, rng, derivs)
        total += radiance
        total_sq += wp.cw_mul(radiance, radiance)
        total_jacobian += path_jacobian
    image[pixel] = total / float(spp)
    stderr[pixel] = standard_error(total, total_sq, spp)
    jacobian[pixel] = total_jacobian / float(spp)


def render_jacobian(scene: Scene | PreparedScene, spp: int | None = None, seed: int | None = None,
                    threads: int | None = None, device: str | None = None):
    """(jacobian (H, W, 3, 8) float32, image (H, W, 3), stderr (H, W, 3)) of `scene` at its own controls.

    `scene` is a Scene or a PreparedScene (`render.prepare`, built once for many renders); spp and seed default
    to the scene's [render] table; the image is `render(scene, spp, seed)`'s up to float rounding (the same paths).
    """
    spp, seed = sampling(scene, spp, seed)
    prepared = prepare(scene, device)
    device = prepared.device
    width, height = prepared.resolution
    n = width * height
    image = wp.zeros(n, dtype=wp.vec3, device=device)
    stderr = wp.zeros(n, dtype=wp.vec3, device=device)
    jacobian = wp.zeros(n, dtype=value_jacobian_mat, device=device)
    launch_ranges(
        render_jacobian_kernel,
        n,
        [prepared.data, coefficient_derivatives(prepared.scene.hair), spp, seed, image, stderr, jacobian],
        threads=threads,
        device=device,
        chunk=tile_pixels(spp),
    )
    return (
        jacobian.numpy().reshape(height, width, 3, -1),
        image.numpy().reshape(height, width, 3),
        stderr.numpy().reshape(height, width, 3),
    )
