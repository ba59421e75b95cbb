"""Render a scene: the loop over pixels and their samples (pbrt's Render and EvaluatePixelSample), shared by the
image and its Jacobian.

    image = render(scene, spp=64, seed=1)                # linear radiance (H, W, 3), row 0 at the top

One kernel factory makes both passes: `render` launches its forward variant, `gradients.render_jacobian` its
gradient variant, which traces the same paths (same seed, same random streams) and also sums each path's
Jacobian. Each sample is a camera ray handed to the path tracer (`integrator.trace_path`, pbrt's Li). On the CPU
the image is split into ranges of pixels launched from a thread pool (a Warp CPU launch runs on one core); on a
GPU one launch covers it. Every pixel owns its random stream, so the image depends on the seed only, not on the
threads or the device (up to the devices' float rounding: the same kernel, compiled by another compiler).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..model.jacobian import CoefficientDerivatives, coefficient_derivatives, value_jacobian_mat
from ..numerics import rand2
from ..parallel import default_threads, launch_ranges
from ..scene import Scene
from .camera import generate_ray
from .integrator import SceneData, trace_path, trace_path_grad
from .prepare import PreparedScene, prepare, sampling

# Pixels per range handed to a thread: fiber pixels cost far more than background ones, and small ranges
# balance the threads at a negligible cost per launch.
TILE_PIXELS = 256
# Above this spp a range holds proportionally fewer pixels, so that one range stays a fraction of a second and
# Ctrl-C, which lets the running ranges finish, stops a render at any spp within about a second.
TILE_SPP = 64
# Ranges each thread gets at least, where ranges of TILE_PIXELS would leave few to share: a 48×48 image was 9 ranges,
# which two threads split 5 to 4, a tenth of the render's wall time with one thread idle (docs/benchmarks.md, issue
# 45); but no range under MIN_TILE_PIXELS, whose launch would cost more than its pixels.
RANGES_PER_THREAD = 8
MIN_TILE_PIXELS = 64


def tile_pixels(spp: int, count: int | None = None, threads: int = 1) -> int:
    """Pixels per range of a render of `count` pixels (None: unknown, only the spp limit) on `threads`."""
    tile = max(1, TILE_PIXELS * TILE_SPP // max(spp, TILE_SPP))
    if count is not None:
        tile = min(tile, max(MIN_TILE_PIXELS, -(-count // (RANGES_PER_THREAD * threads))))
    return tile


@wp.func
def pixel_start(scene: SceneData, pixel: int, seed: int):
    """(column, row, random stream) of a pixel. One stream per pixel: the image does not depend on how pixels are
    split among threads, and the gradient pass with the same seed traces the same paths."""
    width = scene.camera.width_px
    return pixel % width, pixel / width, wp.rand_init(seed, pixel)


@wp.func
def standard_error(total: wp.vec3, total_sq: wp.vec3, spp: int):
    """Standard error of a pixel mean from the sum and the sum of squares of its own samples."""
    n = float(spp)
    mean = total / n
    variance = (total_sq / n - wp.cw_mul(mean, mean)) * (n / wp.max(n - 1.0, 1.0))
    return wp.vec3(
        wp.sqrt(wp.max(variance[0], 0.0) / n),
        wp.sqrt(wp.max(variance[1], 0.0) / n),
        wp.sqrt(wp.max(variance[2], 0.0) / n),
    )


def make_pixel_kernel(differentiable: bool):
    """The pixel kernel: spp paths per pixel, their mean and its standard error; with `differentiable` also the
    mean of the paths' (3, 8) Jacobians. Both variants take the same arguments (the forward one ignores `derivs`
    and `jacobian`), so that one launch serves both. The loop body is pbrt's EvaluatePixelSample: a jittered
    camera ray, traced."""
    trace = trace_path_grad if differentiable else trace_path

    def evaluate_pixels(
        scene: SceneData,
        derivs: CoefficientDerivatives,
        spp: int,
        seed: int,
        image: wp.array(dtype=wp.vec3),
        stderr: wp.array(dtype=wp.vec3),
        jacobian: wp.array(dtype=value_jacobian_mat),
        pixels: wp.array(dtype=wp.int32),
        first: int,
    ):
        pixel = wp.tid() + first
        if pixels.shape[0] > 0:  # a subset (a fit's mini-batch); empty: the whole image in order
            pixel = pixels[pixel]
        px, py, rng = pixel_start(scene, pixel, seed)
        total = wp.vec3(0.0)
        total_sq = wp.vec3(0.0)
        if wp.static(differentiable):
            total_jacobian = value_jacobian_mat()
        for _s in range(spp):
            jitter, rng = rand2(rng)
            origin, direction = generate_ray(scene.camera, px, py, jitter)
            radiance, path_jacobian, rng = trace(scene, origin, direction, rng, derivs)
            total += radiance
            total_sq += wp.cw_mul(radiance, radiance)
            if wp.static(differentiable):
                total_jacobian += path_jacobian
        image[pixel] = total / float(spp)
        stderr[pixel] = standard_error(total, total_sq, spp)
        if wp.static(differentiable):
            jacobian[pixel] = total_jacobian / float(spp)

    # A module of its own for each variant: rendering an image never compiles the gradient pass.
    return wp.kernel(
        evaluate_pixels,
        name="pixel_jacobian_kernel" if differentiable else "pixel_kernel",
        module="unique",
        module_options={"enable_backward": False, "optimization_level": 3},
    )


pixel_kernel = make_pixel_kernel(False)
pixel_jacobian_kernel = make_pixel_kernel(True)


def pixel_indices(pixels, resolution) -> np.ndarray | None:
    """The flat pixel indices (row · width + column) to render, checked; None (every pixel) when `pixels` is."""
    width, height = resolution
    n = width * height
    if pixels is None:
        return None
    flat = np.asarray(pixels)
    if flat.ndim != 1 or not (flat.size == 0 or np.issubdtype(flat.dtype, np.integer)):
        raise ValueError(
            f"pixels must be a 1-D array of integer pixel indices (row * width + column), got shape "
            f"{flat.shape} of {flat.dtype}"
        )
    if flat.size and (flat.min() < 0 or flat.max() >= n):
        raise ValueError(f"pixels must lie in [0, {n}) for a {width}x{height} image, got {flat.min()}..{flat.max()}")
    return flat.astype(np.int32)


def launch_pixels(
    scene: Scene | PreparedScene, spp, seed, threads, device, differentiable: bool, progress=None, pixels=None
):
    """(prepared scene, image, stderr, jacobian or None): the launch of both passes over `pixels` (flat indices;
    default all), its outputs left on the device as flat Warp arrays of n = W·H pixels (vec3, value_jacobian_mat),
    for callers that keep working there (the torch front). On the CPU the pixels are tiled over `threads`; on a GPU
    one launch covers them, on the current Warp stream (`wp.ScopedStream` chooses it)."""
    spp, seed = sampling(scene, spp, seed)
    prepared = prepare(scene, device)
    device = prepared.device
    width, height = prepared.resolution
    n = width * height
    indices = pixel_indices(pixels, prepared.resolution)
    count = n if indices is None else len(indices)
    indices = np.zeros(0, np.int32) if indices is None else indices
    image = wp.zeros(n, dtype=wp.vec3, device=device)
    stderr = wp.zeros(n, dtype=wp.vec3, device=device)
    if differentiable:
        kernel = pixel_jacobian_kernel
        derivs = coefficient_derivatives(prepared.scene.hair)
        jacobian = wp.zeros(n, dtype=value_jacobian_mat, device=device)
    else:
        kernel, derivs, jacobian = pixel_kernel, CoefficientDerivatives(), None
    launch_ranges(
        kernel,
        count,
        [
            prepared.gradient_data() if differentiable else prepared.data,
            derivs,
            spp,
            seed,
            image,
            stderr,
            jacobian,
            wp.array(indices, dtype=wp.int32, device=device),
        ],
        threads=threads,
        device=device,
        chunk=tile_pixels(spp, count, max(1, min(threads or default_threads(), count))),
        progress=progress,
    )
    return prepared, image, stderr, jacobian


def render_pixels(
    scene: Scene | PreparedScene, spp, seed, threads, device, differentiable: bool, progress=None, pixels=None
):
    """(image (H, W, 3), stderr (H, W, 3), jacobian (H, W, 3, 8) or None), NumPy on the host: `launch_pixels`'s
    arrays. Every pixel draws from its own random stream, so a pixel rendered alone has the value it has in the
    whole image; the pixels not rendered are 0."""
    prepared, image, stderr, jacobian = launch_pixels(
        scene, spp, seed, threads, device, differentiable, progress, pixels
    )
    width, height = prepared.resolution
    return (
        image.numpy().reshape(height, width, 3),
        stderr.numpy().reshape(height, width, 3),
        None if jacobian is None else jacobian.numpy().reshape(height, width, 3, -1),
    )


def render_metadata(scene: Scene, spp: int, seed: int) -> dict:
    """What an image's EXR header records of how it was made."""
    from .. import __version__

    return {
        "warp_hair": {
            "version": __version__,
            "scene": scene.source,
            "hair": scene.hair.to_table(),
            "sigma_a": [float(c) for c in scene.hair.absorption],
            "spp": spp,
            "seed": seed,
        }
    }


def render(
    scene: Scene | PreparedScene,
    spp: int | None = None,
    seed: int | None = None,
    threads: int | None = None,
    device: str | None = None,
    progress=None,
    return_stderr: bool = False,
    pixels=None,
):
    """Linear radiance, float32 (H, W, 3), row 0 at the top.

    `scene` is a Scene, or a PreparedScene (`prepare(scene)`) to skip building the BVH again; `device` ("cpu",
    "cuda" or "cuda:N") defaults to the prepared scene's, else "cpu". spp and seed default to the scene's
    [render] table.
    `progress(done, total)` is called as tiles finish.
    With `return_stderr`, returns (image, stderr): the standard error of each pixel's mean, estimated from
    the spread of its own samples. `pixels`: the flat indices (row · width + column) of the pixels to render,
    each as it comes out in the whole image; the others are 0 (a fit's mini-batches).
    """
    image, stderr, _ = render_pixels(scene, spp, seed, threads, device, False, progress, pixels)
    if return_stderr:
        return image, stderr
    return image
