"""Camera rays: orthographic and perspective cameras in Warp, with a NumPy batch front for tests.

Pixel (px, py) covers [px, px + 1) × [py, py + 1) in raster space, py = 0 the TOP row; a jitter in [0, 1)²
places the sample inside it (box filter). Orientation as in pbrt and Mitsuba: seen from the camera, `up` points
to the top of the image and forward × up to the right.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..scene import Camera


@wp.struct
class CameraData:
    origin: wp.vec3
    forward: wp.vec3  # unit
    right: wp.vec3  # unit, towards the right edge of the image
    up: wp.vec3  # unit, towards the top edge of the image
    # Orthographic: half the view's width and height in scene units. Perspective: the tangents of half the
    # horizontal and vertical fields of view (the image plane's half extents at unit distance).
    half_extent: wp.vec2
    width_px: int
    height_px: int
    perspective: int  # 0: orthographic, 1: perspective


@wp.func
def generate_ray(cam: CameraData, px: int, py: int, jitter: wp.vec2):
    """(origin, unit direction) of the ray through pixel (px, py) at `jitter` within it."""
    # Screen coordinates in [-1, 1]: u grows to the right, v upwards, so that row 0 is the top of the image.
    u = 2.0 * (float(px) + jitter[0]) / float(cam.width_px) - 1.0
    v = 1.0 - 2.0 * (float(py) + jitter[1]) / float(cam.height_px)
    offset = u * cam.half_extent[0] * cam.right + v * cam.half_extent[1] * cam.up
    origin = cam.origin + offset
    direction = cam.forward
    if cam.perspective != 0:
        origin = cam.origin
        direction = wp.normalize(cam.forward + offset)
    return origin, direction


def camera_data(camera: Camera) -> CameraData:
    """The kernels' view of a scene `Camera`."""
    forward, right, up = camera.frame()
    width_px, height_px = camera.resolution
    if camera.type == "orthographic":
        half_width = 0.5 * camera.width
    else:
        half_width = math.tan(math.radians(0.5 * camera.fov))
    data = CameraData()
    data.origin = wp.vec3(*camera.origin)
    data.forward = wp.vec3(*forward)
    data.right = wp.vec3(*right)
    data.up = wp.vec3(*up)
    # Square pixels: the vertical extent follows from the horizontal one and the aspect ratio.
    data.half_extent = wp.vec2(half_width, half_width * height_px / width_px)
    data.width_px = width_px
    data.height_px = height_px
    data.perspective = int(camera.type == "perspective")
    return data


@wp.kernel
def _camera_rays_kernel(
    cam: CameraData,
    px: wp.array(dtype=int),
    py: wp.array(dtype=int),
    jitter: wp.array(dtype=wp.vec2),
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    origin, direction = generate_ray(cam, px[i], py[i], jitter[i])
    origins[i] = origin
    directions[i] = direction


def camera_rays(camera: Camera, px, py, jitter=(0.5, 0.5), device=None):
    """(origins, directions), float32 (..., 3): `generate_ray` for every pixel of broadcast arrays px, py.

    `jitter` (..., 2) broadcasts against them too; the default (0.5, 0.5) gives the pixel centres.
    """
    px, py = np.broadcast_arrays(np.asarray(px), np.asarray(py))
    shape = px.shape
    jitter = np.broadcast_to(np.asarray(jitter, dtype=np.float32), (*shape, 2))
    n = px.size
    origins = wp.empty(n, dtype=wp.vec3, device=device)
    directions = wp.empty(n, dtype=wp.vec3, device=device)
    wp.launch(
        _camera_rays_kernel,
        dim=n,
        inputs=[
            camera_data(camera),
            wp.array(px.reshape(-1).astype(np.int32), dtype=int, device=device),
            wp.array(py.reshape(-1).astype(np.int32), dtype=int, device=device),
            wp.array(np.ascontiguousarray(jitter.reshape(-1, 2)), dtype=wp.vec2, device=device),
            origins,
            directions,
        ],
        device=device,
    )
    return origins.numpy().reshape((*shape, 3)), directions.numpy().reshape((*shape, 3))
