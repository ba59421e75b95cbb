"""Benchmark: how many rays start inside another strand's tube on issue 23's interpenetrating swatch.

    python benchmarks/tangled_rays.py [--paths 40000] [--depth 8]

Where strands pass through each other, the renderers part on the rays that start inside another strand's tube
(docs/scenes.md, "Interpenetrating strands"). A path's continuation ray and its shadow ray both start at the
vertex where it scattered, so this counts vertices: it walks paths through the swatch of `benchmarks/vs_peers.py
--interpenetrating` (camera rays through random points of the 64×64 view, then directions drawn from the hair
BSDF at each fiber hit, no lights, no roulette, up to --depth vertices) under each `[render] interpenetration`
rule, and prints, per depth, the share of vertices that lie inside another strand's tube
(`warp_hair.geometry.interpenetration.points_inside_other_strands`) and, under "exit", the share of hits that
are exits. Vertices are counted alike whatever light they carry.
"""

from __future__ import annotations

import argparse

import numpy as np
import warp as wp
from vs_peers import TANGLED_HAIR, TARGET_LIGHTINGS, interpenetrating_swatch, scene_data

from warp_hair.geometry.curves import catmull_rom
from warp_hair.geometry.interpenetration import points_inside_other_strands
from warp_hair.geometry.intersect import FiberGeometry, intersect_fibers_under_rule, shading_frame
from warp_hair.geometry.tubes import FiberBVH
from warp_hair.model.hair_bsdf import HairCoefficients, hair_coefficients, hair_sample, lobe_setup
from warp_hair.model.params import HairParams
from warp_hair.numerics import NO_HIT
from warp_hair.renderer.camera import CameraData, camera_data, generate_ray
from warp_hair.scene import scene_from_dict


@wp.kernel
def walk(
    g: FiberGeometry,
    hair: HairCoefficients,
    cam: CameraData,
    seed: int,
    exits: int,
    position: wp.array2d(dtype=wp.vec3),
    strand: wp.array2d(dtype=wp.int32),
    leaving: wp.array2d(dtype=wp.int32),
):
    """One path per thread: its fiber vertices (strand −1 past its end)."""
    k = wp.tid()
    rng = wp.rand_init(seed, k)
    px = int(wp.randf(rng) * float(cam.width_px))
    py = int(wp.randf(rng) * float(cam.height_px))
    o, d = generate_ray(cam, px, py, wp.vec2(wp.randf(rng), wp.randf(rng)))
    last = int(-1)
    for depth in range(position.shape[1]):
        hit = intersect_fibers_under_rule(g, o, d, NO_HIT, exits, last, -1)
        if hit.t >= NO_HIT:
            return
        x, z, h = shading_frame(g, hit, d)
        y = wp.cross(z, x)
        wo = wp.vec3(-wp.dot(d, x), -wp.dot(d, y), -wp.dot(d, z))
        wi = hair_sample(lobe_setup(hair, wo, h), wp.vec3(wp.randf(rng), wp.randf(rng), wp.randf(rng)))
        position[k, depth] = hit.position
        strand[k, depth] = wp.int32(hit.strand)
        leaving[k, depth] = wp.int32(hit.exit)
        o = hit.position
        d = wp.normalize(wi[0] * x + wi[1] * y + wi[2] * z)
        last = hit.strand


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--paths", type=int, default=40000)
    parser.add_argument("--depth", type=int, default=8)
    args = parser.parse_args(argv)
    fibers = catmull_rom(interpenetrating_swatch())
    scene = scene_from_dict({**scene_data(64, TARGET_LIGHTINGS["front"], 1), "hair": TANGLED_HAIR})
    bvh = FiberBVH(fibers)
    hair = hair_coefficients(HairParams(**TANGLED_HAIR))
    print(f"{args.paths} paths, up to {args.depth} fiber vertices, on issue 23's swatch (Catmull-Rom curves)")
    print("rule   depth: share of vertices inside another strand's tube [share of hits that are exits]")
    for exits, rule in enumerate(("enter", "exit")):
        position = wp.zeros((args.paths, args.depth), dtype=wp.vec3)
        strand = wp.full((args.paths, args.depth), -1, dtype=wp.int32)
        leaving = wp.zeros((args.paths, args.depth), dtype=wp.int32)
        wp.launch(
            walk,
            dim=args.paths,
            inputs=[bvh.geometry, hair, camera_data(scene.camera), 7, exits, position, strand, leaving],
        )
        position, strand, leaving = position.numpy(), strand.numpy(), leaving.numpy().astype(bool)
        valid = strand >= 0
        inside = np.zeros_like(valid)
        inside[valid] = points_inside_other_strands(fibers, position[valid], strand[valid])
        cells = []
        for depth in range(args.depth):
            n = int(valid[:, depth].sum())
            if n == 0:
                break
            share = inside[valid[:, depth], depth].mean()
            exit_share = f" [{leaving[valid[:, depth], depth].mean():.1%}]" if exits else ""
            cells.append(f"{depth + 1}: {share:.1%}{exit_share} of {n}")
        total = inside[valid].mean()
        print(f"{rule:6} " + "; ".join(cells) + f"; all: {total:.1%}")


if __name__ == "__main__":
    main()
