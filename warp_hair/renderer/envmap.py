"""Environment lights: a constant sky or a lat-long (equirectangular) radiance map, importance sampled.

Convention (Mitsuba 3's `envmap` emitter, `direction_to_uv` / `uv_to_direction`): +y is up. A unit
direction d (pointing from the scene toward the sky) has polar angle θ from +y and azimuth φ, with

    d = (sin φ sin θ, cos θ, −cos φ sin θ),    u = φ / 2π = atan2(d.x, −d.z) / 2π  (wrapped into [0, 1)),
                                               v = θ / π.

So u = 0 looks along −z, u = 1/4 along +x, u = 1/2 along +z; v = 0 is +y and v = 1 is −y. An H×W image
(row 0 at the top) covers [0, 1)² with pixel (row y, column x) spanning u ∈ [x/W, (x+1)/W) and
v ∈ [y/H, (y+1)/H): its centre sits at φ = 2π(x + 0.5)/W (as in Mitsuba) and θ = π(y + 0.5)/H.
Radiance is a nearest-pixel lookup, i.e. piecewise constant over those cells (Mitsuba interpolates
bilinearly between rows centred on v = y/(H−1); here rows are cells, so the poles have no special row).

Sampling picks a pixel with probability ∝ luminance × sin θ (the lat-long map's solid-angle Jacobian
dω = 2π² sin θ du dv), then a point uniform in (u, v) within it, so the solid-angle density is
p(u, v) / (2π² sin θ). A constant sky, or an image with no luminance anywhere, is sampled uniformly on
the sphere (density 1/4π).

    env, keepalive = environment_data(image=img, scale=2.0)   # or radiance=(r, g, b)
    img = from_blender(blender_img, rotation_z=30.0)           # a Blender world's map, for the scene exported Y up
    # in a kernel:  L = env_radiance(env, d);  d, pdf = env_sample(env, u);  pdf = env_pdf(env, d)
"""

import math

import numpy as np
import warp as wp

from ..numerics import INV_FOUR_PI, PI, TWO_PI

INV_TWO_PI_SQUARED = wp.constant(1.0 / (2.0 * math.pi**2))
# Largest float32 below 1: caps coordinates and in-pixel offsets so that rounding cannot push them
# onto the next pixel, or past the last one.
ONE_MINUS_ULP = wp.constant(float(np.nextafter(np.float32(1.0), np.float32(0.0))))
# The density grows as 1/sin θ toward the poles; this floor keeps it finite there (a cap of
# solid angle ~1e-12 sr is affected).
SIN_THETA_MIN = wp.constant(1.0e-6)

# Rec. 709 / sRGB luminance of linear RGB (Mitsuba also samples its envmap by luminance).
LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])


@wp.struct
class EnvironmentData:
    """An environment light as kernels see it. Build it with `environment_data`."""

    radiance: wp.vec3  # the constant sky, when has_image == 0
    scale: float  # multiplies the radiance of either kind
    image: wp.array2d(dtype=wp.vec3)  # H×W linear radiance, row 0 at the top
    marginal_cdf: wp.array(dtype=float)  # H + 1 entries, 0 … 1: the rows
    conditional_cdf: wp.array2d(dtype=float)  # H × (W + 1), each row 0 … 1: the columns of that row
    has_image: int
    importance: int  # 0 where the image has no luminance to sample by: sample uniformly instead


@wp.func
def direction_to_uv(d: wp.vec3):
    """Lat-long coordinates in [0, 1)² of the unit direction d."""
    # atan2 for θ keeps its precision near the poles, where acos(d.y) loses it.
    theta = wp.atan2(wp.sqrt(d[0] * d[0] + d[2] * d[2]), d[1])
    u = wp.atan2(d[0], -d[2]) / TWO_PI
    if u < 0.0:
        u = u + 1.0
    return wp.vec2(wp.min(u, ONE_MINUS_ULP), wp.min(theta / PI, ONE_MINUS_ULP))


@wp.func
def uv_to_direction(uv: wp.vec2):
    """The unit direction at lat-long coordinates uv (inverse of `direction_to_uv`)."""
    theta = PI * uv[1]
    phi = TWO_PI * uv[0]
    sin_theta = wp.sin(theta)
    return wp.vec3(wp.sin(phi) * sin_theta, wp.cos(theta), -wp.cos(phi) * sin_theta)


@wp.func
def _pixel(env: EnvironmentData, uv: wp.vec2):
    """(column, row) of the pixel covering uv, clamped so that no input can index outside the image."""
    w = env.image.shape[1]
    h = env.image.shape[0]
    x = wp.clamp(int(uv[0] * float(w)), 0, w - 1)
    y = wp.clamp(int(uv[1] * float(h)), 0, h - 1)
    return wp.vec2i(x, y)


@wp.func
def _sin_theta(d: wp.vec3):
    return wp.max(wp.sqrt(d[0] * d[0] + d[2] * d[2]), SIN_THETA_MIN)


@wp.func
def _find_interval(cdf: wp.array(dtype=float), u: float):
    """The bin i with cdf[i] ≤ u < cdf[i + 1], for u in [0, 1) and cdf running from 0 to 1.

    Taking the first i with cdf[i + 1] > u skips bins of zero probability, which a sample must never land in.
    """
    lo = int(0)
    hi = cdf.shape[0] - 2
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid + 1] > u:
            hi = mid
        else:
            lo = mid + 1
    return lo


@wp.func
def _remap(cdf: wp.array(dtype=float), i: int, u: float):
    """Position of u within bin i of cdf, in [0, 1): a fresh uniform for the next dimension or the jitter."""
    t = (u - cdf[i]) / (cdf[i + 1] - cdf[i])
    return wp.clamp(t, 0.0, ONE_MINUS_ULP)


@wp.func
def _uv_density(env: EnvironmentData, pixel: wp.vec2i):
    """p(u, v) on the unit square: the pixel's probability divided by its area 1/(W H)."""
    x = pixel[0]
    y = pixel[1]
    row = env.conditional_cdf[y]
    p_row = env.marginal_cdf[y + 1] - env.marginal_cdf[y]
    p_column = row[x + 1] - row[x]
    return p_row * p_column * float(env.image.shape[0] * env.image.shape[1])


@wp.func
def _uniform_sphere(u: wp.vec2):
    return uv_to_direction(wp.vec2(u[1], wp.acos(wp.clamp(1.0 - 2.0 * u[0], -1.0, 1.0)) / PI))


@wp.func
def env_radiance(env: EnvironmentData, d: wp.vec3):
    """Radiance arriving from direction d (toward the sky): nearest pixel × scale, or the constant × scale."""
    if env.has_image == 0:
        return env.radiance * env.scale
    pixel = _pixel(env, direction_to_uv(d))
    return env.image[pixel[1], pixel[0]] * env.scale


@wp.func
def env_pdf(env: EnvironmentData, d: wp.vec3):
    """Solid-angle density with which `env_sample` returns the unit direction d (for MIS)."""
    if env.importance == 0:
        return INV_FOUR_PI
    p_uv = _uv_density(env, _pixel(env, direction_to_uv(d)))
    return p_uv * INV_TWO_PI_SQUARED / _sin_theta(d)


@wp.func
def env_sample(env: EnvironmentData, u: wp.vec2):
    """A direction toward the sky from two uniforms in [0, 1), and its solid-angle density.

    The density is that of the pixel drawn; it equals `env_pdf` at the returned direction except when
    rounding puts the direction on the neighbouring side of a pixel edge.
    """
    if env.importance == 0:
        return _uniform_sphere(u), INV_FOUR_PI
    y = _find_interval(env.marginal_cdf, u[0])
    row = env.conditional_cdf[y]
    x = _find_interval(row, u[1])
    uv = wp.vec2(
        (float(x) + _remap(row, x, u[1])) / float(env.image.shape[1]),
        (float(y) + _remap(env.marginal_cdf, y, u[0])) / float(env.image.shape[0]),
    )
    d = uv_to_direction(uv)
    return d, _uv_density(env, wp.vec2i(x, y)) * INV_TWO_PI_SQUARED / _sin_theta(d)


def _row_mean_sin_theta(height: int) -> np.ndarray:
    """Mean of sin θ over each row's band of θ: weights pixels by their exact solid angle."""
    cos_edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (cos_edges[:-1] - cos_edges[1:]) * height / np.pi


# `peak_irradiance` reads a map at no more than these cells (area-weighted means; the cosine it is integrated
# against is smooth) and tries this many orientations of the surface, spread evenly over the sphere.
PEAK_CELLS = (64, 128)
PEAK_ORIENTATIONS = 1024


def peak_irradiance(radiance=None, image=None, above_least: bool = False) -> float:
    """The most irradiance the environment gives a surface, over the surface's orientations, in the mean of the three
    channels: π L for a constant sky, about a sun's irradiance plus the sky around it for a map with one. With
    `above_least`, that of its radiance less the least it sends anywhere (0 for a constant sky, about a sun's
    irradiance for a map with one), what a light sampler weighs it by (light_sampler.py)."""
    if image is None:
        constant = _checked_radiance(0.0 if radiance is None else radiance)
        return 0.0 if above_least else math.pi * float(np.mean(constant))
    radiance = _checked_image(image).mean(axis=2, dtype=np.float64)
    if above_least:
        radiance = radiance - radiance.min()
    height, width = radiance.shape
    # Each pixel's radiance × solid angle (2π²/(HW) × its row's mean sin θ), summed into cells seen from their centres.
    power = radiance * (_row_mean_sin_theta(height) * (2.0 * np.pi**2 / (height * width)))[:, None]
    rows, cols = (min(n, cells) for n, cells in zip((height, width), PEAK_CELLS))
    cell = ((np.arange(height) * rows // height)[:, None] * cols + (np.arange(width) * cols // width)[None, :]).ravel()
    cells = np.bincount(cell, weights=power.ravel(), minlength=rows * cols)
    directions = pixel_directions(cols, rows).reshape(-1, 3)
    normals = np.concatenate([_even_directions(PEAK_ORIENTATIONS), directions[[int(np.argmax(cells))]]])
    return float(np.max(np.maximum(normals @ directions.T, 0.0) @ cells))


def pixel_directions(width: int, height: int) -> np.ndarray:
    """(H, W, 3) unit directions of the centres of a W×H map's pixels (`uv_to_direction`)."""
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width
    sin_theta = np.sin(theta)[:, None]
    x, y, z = np.sin(phi)[None, :] * sin_theta, np.cos(theta)[:, None], -np.cos(phi)[None, :] * sin_theta
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def _even_directions(n: int) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the sphere (a Fibonacci lattice)."""
    y = 1.0 - (2.0 * np.arange(n) + 1.0) / n
    phi = np.pi * (3.0 - math.sqrt(5.0)) * np.arange(n)
    r = np.sqrt(1.0 - y * y)
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=-1)


def _cdf(weights: np.ndarray) -> np.ndarray:
    """CDFs along the last axis, 0 first and exactly 1 last; uniform where a row has no weight."""
    total = weights.sum(axis=-1, keepdims=True)
    uniform = np.broadcast_to(np.arange(1, weights.shape[-1] + 1) / weights.shape[-1], weights.shape)
    cdf = np.where(total > 0.0, np.cumsum(weights, axis=-1) / np.where(total > 0.0, total, 1.0), uniform)
    cdf[..., -1] = 1.0
    return np.concatenate([np.zeros((*weights.shape[:-1], 1)), cdf], axis=-1)


def _sampling_tables(image: np.ndarray):
    """Marginal CDF over rows, conditional CDFs over columns, and whether there is anything to sample."""
    luminance = np.maximum(image.astype(np.float64) @ LUMINANCE_WEIGHTS, 0.0)
    weights = luminance * _row_mean_sin_theta(image.shape[0])[:, None]
    return _cdf(weights.sum(axis=1)), _cdf(weights), bool(weights.sum() > 0.0)


def _checked_image(image) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"image must be (H, W, 3) linear RGB radiance, got shape {image.shape}")
    if not np.all(np.isfinite(image)) or np.any(image < 0.0):
        raise ValueError("image radiance must be finite and non-negative")
    return image


def _checked_radiance(radiance) -> np.ndarray:
    rgb = np.broadcast_to(np.asarray(radiance, dtype=np.float64), (3,))
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0.0):
        raise ValueError(f"radiance must be finite and non-negative, got {radiance}")
    return rgb


def environment_data(radiance=None, image=None, scale: float = 1.0, device="cpu"):
    """An EnvironmentData for kernels, and the arrays it points to (keep them alive while it is used).

    Give at most one of `radiance` (a scalar or RGB triple: a constant sky) or `image` (float32 (H, W, 3)
    linear radiance in the lat-long convention of this module, row 0 at the top); neither is a black sky,
    so that a scene without an environment can pass the same struct. `scale` multiplies either.
    """
    if radiance is not None and image is not None:
        raise ValueError("give radiance or image, not both")
    if not (math.isfinite(scale) and scale >= 0.0):
        raise ValueError(f"scale must be finite and non-negative, got {scale}")
    env = EnvironmentData()
    env.scale = float(scale)
    if image is None:
        env.radiance = wp.vec3(*_checked_radiance(0.0 if radiance is None else radiance))
        env.has_image = 0
        env.importance = 0
        return env, ()
    image = _checked_image(image)
    marginal, conditional, has_luminance = _sampling_tables(image)
    env.radiance = wp.vec3(0.0)
    env.has_image = 1
    env.importance = int(has_luminance)
    env.image = wp.array(image, dtype=wp.vec3, device=device)
    env.marginal_cdf = wp.array(marginal.astype(np.float32), dtype=float, device=device)
    env.conditional_cdf = wp.array(conditional.astype(np.float32), dtype=float, device=device)
    return env, (env.image, env.marginal_cdf, env.conditional_cdf)


def from_blender(image, rotation_z: float = 0.0) -> np.ndarray:
    """A lat-long map as Blender lights a Z-up scene with it, re-indexed for that scene exported Y up.

    `image` (H, W, 3), row 0 at the top, is the file an Environment Texture node reads; `rotation_z` is the Z
    rotation in degrees of a Mapping node between the world's Generated coordinate and that texture (0 without
    one). The scene must come over with Blender's USD export `convert_orientation` (forward −Z, up Y), which
    maps Blender's (x, y, z) to (x, z, −y), as the camera must (README, "Bringing your own groom").

    Why a column roll: Cycles looks the map up at u = (π − atan2(y, x)) / 2π, v = 1 − acos(z) / π of the
    (rotated) direction with v = 0 the bottom row (`direction_to_equirectangular`, range (−2π, π, −π, π), in
    Cycles' kernel/geom); this module at u = atan2(x, −z) / 2π, v = acos(y) / π with v = 0 the top row. Under
    that change of axes both keep the same up and polar angle, so v agrees, and u differs by a constant:
    Cycles' u = ours + 1/4 − rotation_z / 360. The result is the image turned by the nearest whole number of
    columns, exact when rotation_z is a multiple of 360 / W degrees and within half a column's angle otherwise.
    """
    image = _checked_image(image)
    if not math.isfinite(rotation_z):
        raise ValueError(f"rotation_z must be a finite angle in degrees, got {rotation_z!r}")
    width = image.shape[1]
    return np.roll(image, round(width * (rotation_z / 360.0 - 0.25)) % width, axis=1)
