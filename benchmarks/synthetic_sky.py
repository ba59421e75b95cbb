"""A synthetic lat-long HDRI made here (no downloads): a small bright sun off every axis over coloured gradients.

    from synthetic_sky import synthetic_sky
    image = synthetic_sky(sun=(-0.35, 0.45, 0.82))      # float32 (H, W, 3), warp-hair's lat-long convention

Strongly non-uniform and asymmetric on purpose, so that a renderer that reads the map with another orientation
(u mirrored, v upside down, turned about the up axis, +z up instead of +y) lights the scene visibly differently:
- a sun disc of angular radius `sun_radius` degrees around the direction `sun` (toward the sun), whose
  radiance gives a surface facing it the irradiance `sun_irradiance` (about what the shipped targets' directional
  lights give, 3);
- a sky from a warm horizon to a blue zenith, brighter toward the sun's azimuth;
- a ground that is reddish on one side (+x) and greenish on the other (−x), darker toward −z.
Each pixel's radiance is that of its centre's direction (warp_hair/renderer/envmap.py: +y up, u = 0 looking
down −z, u = 1/4 along +x, row 0 at the top).
"""

from __future__ import annotations

import numpy as np

from warp_hair.renderer.envmap import pixel_directions


def synthetic_sky(
    width: int = 256,
    height: int = 128,
    sun=(-0.35, 0.45, 0.82),
    sun_radius: float = 4.0,
    sun_irradiance: float = 3.0,
    sky: float = 0.25,
) -> np.ndarray:
    """The map (see the module docstring): float32 (height, width, 3) linear radiance."""
    d = pixel_directions(width, height)
    s = np.asarray(sun, dtype=np.float64)
    s /= np.linalg.norm(s)
    up = np.clip(d[..., 1], -1.0, 1.0)[..., None]
    toward_sun = 0.5 + 0.5 * (d[..., [0, 2]] @ s[[0, 2]])[..., None] / max(np.linalg.norm(s[[0, 2]]), 1e-9)
    horizon, zenith = np.array([1.0, 0.75, 0.5]), np.array([0.25, 0.45, 1.0])
    heavens = sky * (horizon + (zenith - horizon) * np.sqrt(np.clip(up, 0.0, 1.0))) * (0.5 + toward_sun)
    side = d[..., :1]  # +x reddish, −x greenish; darker toward −z
    ground = 0.4 * sky * (np.array([0.5, 0.4, 0.3]) + side * np.array([0.3, -0.15, -0.1])) * (1.2 + 0.6 * d[..., 2:3])
    image = np.where(up > 0.0, heavens, ground)
    disc = d @ s > np.cos(np.radians(sun_radius))
    # The disc's solid angle as the pixels cover it, so that its irradiance is the one asked for.
    theta = np.pi * (np.arange(height) + 0.5) / height
    pixel_solid_angle = (2.0 * np.pi / width) * (np.pi / height) * np.sin(theta)[:, None] * np.ones((1, width))
    cosine = np.clip(d @ s, 0.0, None)
    radiance = sun_irradiance / float(np.sum(pixel_solid_angle[disc] * cosine[disc]))
    image[disc] = radiance * np.array([1.0, 0.95, 0.85])
    return image.astype(np.float32)
