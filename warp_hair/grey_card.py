"""A grey card's radiance without rendering: a Lambertian reflector of known reflectance in a scene's lights.

    normal = card_normal(scene, "camera")           # or a vector in scene coordinates
    radiance = card_radiance(scene, 0.18, normal)   # (3,) float64, what the camera sees of the card

A photographer's grey card is a flat Lambertian reflector of reflectance ρ. Its radiance, the same toward every
viewer, is ρ/π times the irradiance E on it (Lambert's law), so

    L = ρ/π · E,    E = Σ_directional E_l · max(0, n·(−d_l))  +  ∫_{n·ω > 0} L_env(ω) (n·ω) dω,

with d_l the way light l travels and E_l its `irradiance` on a surface facing it (`scene.DirectionalLight`), as
warp-hair's own `[card]` is shaded (renderer/material.py: S cos θ = ρ cos θ / π, lit by a directional light's
irradiance). The environment's integral is taken from its map as the renderer sees it (renderer/envmap.py: a
lat-long map, piecewise constant over its pixels, +y up): each pixel split into s×s cells of exact solid angle,
each cell weighted by the cosine at its centre; a constant sky gives π L_env exactly.

What this leaves out, where a render would count it: the card's shadow (by the hair or anything else) and the
light the hair reflects onto it. A card the user masks in a photo must therefore be in the open: an unshadowed
part of it, facing the lights, away from the hair.
"""

from __future__ import annotations

import math

import numpy as np

from .scene import DirectionalLight, EnvironmentLight

# Cells the environment's integral evaluates the cosine in, at most (about): each pixel is split into s×s.
ENVIRONMENT_CELLS = 1 << 22
MAX_SPLIT = 16
# Below this cosine between the card's normal and the view direction the camera sees the card edge-on.
MIN_VIEW_COSINE = math.cos(math.radians(85.0))


def card_normal(scene, normal, where: str = "normal") -> np.ndarray:
    """The card's unit normal, float64 (3,), on the side the camera sees: "camera" is the camera's view direction
    reversed (a card held parallel to the image plane, as warp-hair's own `[card]` is); a vector is taken in
    scene coordinates, its sign turned toward the camera (the camera sees the face it sees). A card the camera
    sees within 5° of edge-on is an error."""
    forward, _, _ = scene.camera.frame()
    if isinstance(normal, str):
        if normal != "camera":
            raise ValueError(f'{where} = {normal!r}; allowed: "camera" or a vector [x, y, z] in scene coordinates')
        return -forward
    try:
        n = np.asarray(normal, dtype=np.float64)
    except (TypeError, ValueError):
        n = np.zeros(0)
    if n.shape != (3,) or not np.isfinite(n).all() or not n.any():
        raise ValueError(f'{where} = {normal!r}; allowed: "camera" or a finite nonzero vector [x, y, z]')
    n = n / np.linalg.norm(n)
    facing = -float(n @ forward)
    if abs(facing) < MIN_VIEW_COSINE:
        toward = ((-forward).round(4) + 0.0).tolist()
        angle = math.degrees(math.acos(min(abs(facing), 1.0)))
        raise ValueError(
            f"{where} = {list(normal)} is {angle:.1f}° from the direction to the camera {toward}: the camera sees "
            "the card edge-on; a card must face the camera within 85°"
        )
    return n if facing > 0 else -n


def card_radiance(scene, reflectance, normal) -> np.ndarray:
    """(3,) float64: the radiance of a Lambertian card of RGB (or grey) `reflectance` with unit `normal` (from
    `card_normal`) in `scene`'s lights, ρ/π · E (see the module docstring)."""
    rho = np.broadcast_to(np.asarray(reflectance, dtype=np.float64), (3,))
    return rho / math.pi * irradiance(scene.lights, np.asarray(normal, dtype=np.float64))


def irradiance(lights, normal: np.ndarray) -> np.ndarray:
    """(3,) float64: the irradiance the lights give a surface with unit `normal`, nothing in between."""
    total = np.zeros(3)
    for light in lights:
        if isinstance(light, DirectionalLight):
            cosine = max(0.0, -float(np.asarray(light.direction) @ normal))
            total += np.asarray(light.irradiance, dtype=np.float64) * cosine
        elif isinstance(light, EnvironmentLight):
            if light.image is None:
                total += math.pi * np.asarray(light.radiance, dtype=np.float64)
            else:
                total += environment_irradiance(light.image, normal)
        else:
            raise TypeError(f"no irradiance rule for a light of type {type(light).__name__}")
    return total


def environment_irradiance(image: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(3,): ∫ L(ω) max(0, n·ω) dω over a lat-long map (H, W, 3), as renderer/envmap.py lays it out: pixel (row y,
    column x) covers θ ∈ [π y/H, π (y+1)/H) from +y and φ ∈ [2π x/W, 2π (x+1)/W), ω = (sin φ sin θ, cos θ,
    −cos φ sin θ). Each pixel is split into s×s cells (s up to MAX_SPLIT, about ENVIRONMENT_CELLS cells in all);
    a cell's solid angle is exact, Δφ (cos θ₀ − cos θ₁), its cosine taken at its centre."""
    h, w = image.shape[:2]
    s = int(max(1, min(MAX_SPLIT, math.isqrt(max(ENVIRONMENT_CELLS // (h * w), 1)))))
    theta_edges = np.linspace(0.0, math.pi, h * s + 1)
    theta = 0.5 * (theta_edges[:-1] + theta_edges[1:])
    band = np.cos(theta_edges[:-1]) - np.cos(theta_edges[1:])  # ∫ sin θ dθ over each row of cells
    phi = (np.arange(w * s) + 0.5) * (2.0 * math.pi / (w * s))
    d_phi = 2.0 * math.pi / (w * s)
    nx, ny, nz = (float(v) for v in normal)
    total = np.zeros(3)
    pixels = image.astype(np.float64)
    for y in range(h):  # one row of pixels at a time: s rows of cells, W·s columns each
        rows = slice(y * s, (y + 1) * s)
        sin_t, cos_t = np.sin(theta[rows])[:, None], np.cos(theta[rows])[:, None]
        cosine = nx * np.sin(phi)[None, :] * sin_t + ny * cos_t - nz * np.cos(phi)[None, :] * sin_t
        weights = np.maximum(cosine, 0.0) * band[rows, None] * d_phi  # (s, W s)
        per_pixel = weights.sum(axis=0).reshape(w, s).sum(axis=1)  # (W,)
        total += per_pixel @ pixels[y]
    return total
