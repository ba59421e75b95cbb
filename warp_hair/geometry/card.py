"""The diffuse backing card: swatches are photographed lying on a card.

An infinite plane perpendicular to the camera's view direction, a given distance behind the farthest fiber
point, two-sided Lambertian with an RGB albedo.
"""

import numpy as np
import warp as wp

from ..numerics import NO_HIT


@wp.struct
class CardData:
    enabled: int
    point: wp.vec3
    normal: wp.vec3  # unit, facing the camera
    albedo: wp.vec3


def card_plane(card, camera, fiber_bounds):
    """(point, unit normal facing the camera), float64: the plane of `card` behind fibers with bounds (lo, hi)."""
    origin = np.asarray(camera.origin, dtype=np.float64)
    forward = np.asarray(camera.target, dtype=np.float64) - origin
    forward /= np.linalg.norm(forward)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in fiber_bounds)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    depth = np.max((corners - origin) @ forward) + card.distance
    return origin + depth * forward, -forward


def card_data(card, camera, fiber_bounds) -> CardData:
    """The card of a scene (None: disabled) behind fibers with bounds (lo, hi), as the kernels need it."""
    data = CardData()
    data.enabled = 0
    data.point = wp.vec3(0.0, 0.0, 0.0)
    data.normal = wp.vec3(0.0, 0.0, 1.0)
    data.albedo = wp.vec3(0.0, 0.0, 0.0)
    if card is None:
        return data
    point, normal = card_plane(card, camera, fiber_bounds)
    data.enabled = 1
    data.point = wp.vec3(*point)
    data.normal = wp.vec3(*normal)
    data.albedo = wp.vec3(*card.albedo)
    return data


@wp.func
def card_distance(card: CardData, origin: wp.vec3, direction: wp.vec3):
    """Distance along the ray to the card, NO_HIT if it misses or the card is disabled."""
    if card.enabled == 0:
        return NO_HIT
    denom = wp.dot(direction, card.normal)
    if wp.abs(denom) < 1.0e-12:
        return NO_HIT
    t = wp.dot(card.point - origin, card.normal) / denom
    if t <= 0.0:
        return NO_HIT
    return t
