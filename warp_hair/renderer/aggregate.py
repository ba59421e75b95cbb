"""What a ray can meet in a scene, asked as one question (pbrt's aggregate): the fibers under the scene's
interpenetration rule and the backing card.

    hit = intersect_scene(surfaces, o, d, strand, tube)   # the nearest surface: hit.kind HAIR, CARD or MISS
    occluded_scene(surfaces, o, d, strand, tube)           # whether anything blocks a ray toward a light at infinity

`strand` and `tube` are those the ray leaves (−1 for none): the "exit" rule skips the strand, the "enter" rule the
tube (geometry/intersect.py says why). The tracer knows neither the card nor the rule: it asks these two.
"""

import warp as wp

from ..geometry.card import CardData, card_distance
from ..geometry.intersect import FiberGeometry, FiberHit, fibers_occluded_under_rule, intersect_fibers_under_rule
from ..numerics import NO_HIT

# As the integrator: forward only, -O3.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

# What a ray meets (material.Vertex.kind for the first two).
HAIR = wp.constant(0)
CARD = wp.constant(1)
MISS = wp.constant(-1)


@wp.struct
class Surfaces:
    fibers: FiberGeometry
    card: CardData
    exits: int  # 1: [render] interpenetration = "exit" (geometry.intersect, the "exits" rule)


@wp.struct
class SurfaceHit:
    kind: int  # HAIR, CARD or MISS
    t: float  # along the unit ray to the surface met; NO_HIT on a miss
    fiber: FiberHit  # the closest fiber hit (where kind is HAIR, the one met)


@wp.func
def intersect_scene(surfaces: Surfaces, origin: wp.vec3, direction: wp.vec3, strand: int, tube: int):
    """The nearest surface along the ray: the closest fiber hit under the scene's rule, or the card if nearer."""
    hit = SurfaceHit()
    hit.fiber = intersect_fibers_under_rule(surfaces.fibers, origin, direction, NO_HIT, surfaces.exits, strand, tube)
    t_card = card_distance(surfaces.card, origin, direction)
    hit.kind = HAIR
    hit.t = hit.fiber.t
    if t_card < hit.fiber.t:
        hit.kind = CARD
        hit.t = t_card
    if hit.t >= NO_HIT:
        hit.kind = MISS
    return hit


@wp.func
def occluded_scene(surfaces: Surfaces, origin: wp.vec3, direction: wp.vec3, strand: int, tube: int):
    """Whether a ray toward a light at infinity is blocked, by the card or by a fiber under the scene's rule."""
    if card_distance(surfaces.card, origin, direction) < NO_HIT:
        return True
    return fibers_occluded_under_rule(surfaces.fibers, origin, direction, NO_HIT, surfaces.exits, strand, tube)
