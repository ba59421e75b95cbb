"""NumPy front of the device ray queries: `intersect` (the closest hit and its shading frame), `distance` (the
closest hit's distance and segment alone) and `occluded` over batches of rays against a `FiberBVH`, for tests,
the calibration's visibility and users' own probes. `rule` is the scene's `[render] interpenetration`: "enter"
(only entering hits) or "exit" (exits too, except on the strand `skip_strand` the rays leave; intersect.py's
`intersect_fibers_exits`)."""

from __future__ import annotations

import numpy as np
import warp as wp

from .intersect import (
    FiberGeometry,
    closest_tube,
    closest_tube_exits,
    fibers_occluded_under_rule,
    intersect_fibers_under_rule,
    shading_frame,
)
from .tubes import FiberBVH

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _intersect_kernel(
    g: FiberGeometry,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    t_max: wp.array(dtype=float),
    exits: int,
    skip_strand: int,
    t: wp.array(dtype=float),
    segment: wp.array(dtype=wp.int32),
    strand: wp.array(dtype=wp.int32),
    position: wp.array(dtype=wp.vec3),
    tangent: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    shading_tangent: wp.array(dtype=wp.vec3),
    shading_normal: wp.array(dtype=wp.vec3),
    shading_h: wp.array(dtype=float),
    exit: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    hit = intersect_fibers_under_rule(g, origins[k], directions[k], t_max[k], exits, skip_strand, -1)
    t[k] = hit.t
    segment[k] = wp.int32(hit.segment)
    strand[k] = wp.int32(hit.strand)
    position[k] = hit.position
    tangent[k] = hit.tangent
    normal[k] = hit.normal
    h[k] = hit.h
    exit[k] = wp.int32(hit.exit)
    if hit.segment >= 0:
        x, z, hs = shading_frame(g, hit, directions[k])
        shading_tangent[k] = x
        shading_normal[k] = z
        shading_h[k] = hs


@wp.kernel
def _distance_kernel(
    g: FiberGeometry,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    t_max: wp.array(dtype=float),
    exits: int,
    skip_strand: int,
    t: wp.array(dtype=float),
    segment: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    if exits != 0:
        tube, t_hit, _exit = closest_tube_exits(g, origins[k], directions[k], t_max[k], skip_strand)
    else:
        tube, t_hit, _exit = closest_tube(g, origins[k], directions[k], t_max[k], -1)
    t[k] = t_hit
    segment[k] = wp.int32(-1)
    if tube >= 0:  # g.segment is empty in an empty scene: read it only on a hit
        segment[k] = g.segment[tube]


@wp.kernel
def _occluded_kernel(
    g: FiberGeometry,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    t_max: wp.array(dtype=float),
    exits: int,
    skip_strand: int,
    blocked: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    blocked[k] = wp.where(
        fibers_occluded_under_rule(g, origins[k], directions[k], t_max[k], exits, skip_strand, -1), 1, 0
    )


def _rays(bvh, origins, directions, t_max):
    """Device arrays of origins, unit directions and t_max (a scalar or one per ray, capped at NO_HIT)."""
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if origins.shape != directions.shape:
        raise ValueError(f"origins {origins.shape} and directions {directions.shape} differ in shape")
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    t_max = np.minimum(np.broadcast_to(np.asarray(t_max, dtype=np.float64), len(origins)), 1.0e30)
    return (
        wp.array(origins.astype(np.float32), dtype=wp.vec3, device=bvh.device),
        wp.array(directions.astype(np.float32), dtype=wp.vec3, device=bvh.device),
        wp.array(t_max.astype(np.float32), dtype=float, device=bvh.device),
    )


def _rule(rule, skip_strand):
    """(exits flag, strand to skip) for the kernels."""
    if rule not in ("enter", "exit"):
        raise ValueError(f"rule must be 'enter' or 'exit', got {rule!r}")
    return int(rule == "exit"), int(skip_strand)


def intersect(bvh: FiberBVH, origins, directions, t_max=np.inf, rule="enter", skip_strand=-1) -> dict:
    """Closest hits of N rays (origins, directions (N, 3); directions are normalized here; t_max a scalar or
    (N,)) under `rule` (see the module docstring).

    Returns numpy arrays: t (N,) (np.inf on a miss), segment and strand (N,) (−1 on a miss), position,
    tangent, normal (N, 3) and h (N,), and the BSDF's frame from `shading_frame`: shading_tangent,
    shading_normal (N, 3) and shading_h (N,) (zeros on a miss); exit (N,) bool, where the ray leaves a tube.
    """
    exits, skip = _rule(rule, skip_strand)
    o, d, limit = _rays(bvh, origins, directions, t_max)
    n = len(o)
    device = bvh.device
    out = {
        "t": wp.empty(n, dtype=float, device=device),
        "segment": wp.empty(n, dtype=wp.int32, device=device),
        "strand": wp.empty(n, dtype=wp.int32, device=device),
        "position": wp.empty(n, dtype=wp.vec3, device=device),
        "tangent": wp.empty(n, dtype=wp.vec3, device=device),
        "normal": wp.empty(n, dtype=wp.vec3, device=device),
        "h": wp.empty(n, dtype=float, device=device),
        "shading_tangent": wp.zeros(n, dtype=wp.vec3, device=device),
        "shading_normal": wp.zeros(n, dtype=wp.vec3, device=device),
        "shading_h": wp.zeros(n, dtype=float, device=device),
        "exit": wp.zeros(n, dtype=wp.int32, device=device),
    }
    if n:
        wp.launch(
            _intersect_kernel, dim=n, inputs=[bvh.geometry, o, d, limit, exits, skip, *out.values()], device=device
        )
    result = {key: value.numpy() for key, value in out.items()}
    result["t"] = np.where(result["segment"] >= 0, result["t"].astype(np.float64), np.inf)
    result["exit"] = result["exit"].astype(bool)
    return result


def distance(bvh: FiberBVH, origins, directions, t_max=np.inf, rule="enter", skip_strand=-1) -> tuple:
    """(t, segment), each (N,): the distance to the closest hit (np.inf on a miss) and its segment (−1), as
    `intersect` finds them, without its hit point and frame: what Embree's closest-hit query returns, for a
    like-for-like timing of the traversal (benchmarks/profile_render.py) and for depth maps."""
    exits, skip = _rule(rule, skip_strand)
    o, d, limit = _rays(bvh, origins, directions, t_max)
    t = wp.empty(len(o), dtype=float, device=bvh.device)
    segment = wp.empty(len(o), dtype=wp.int32, device=bvh.device)
    if len(o):
        wp.launch(
            _distance_kernel, dim=len(o), inputs=[bvh.geometry, o, d, limit, exits, skip, t, segment], device=bvh.device
        )
    segment = segment.numpy()
    return np.where(segment >= 0, t.numpy().astype(np.float64), np.inf), segment


def occluded(bvh: FiberBVH, origins, directions, t_max=np.inf, rule="enter", skip_strand=-1) -> np.ndarray:
    """(N,) bool: whether each ray has a hit under `rule` before t_max (`fibers_occluded`, batched)."""
    exits, skip = _rule(rule, skip_strand)
    o, d, limit = _rays(bvh, origins, directions, t_max)
    blocked = wp.zeros(len(o), dtype=wp.int32, device=bvh.device)
    if len(o):
        wp.launch(
            _occluded_kernel, dim=len(o), inputs=[bvh.geometry, o, d, limit, exits, skip, blocked], device=bvh.device
        )
    return blocked.numpy().astype(bool)
