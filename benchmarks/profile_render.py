"""Profile: where a standard-swatch render and a fit iteration spend their time (preparation, BVH build,
traversal of each kind of ray, shading).

    python benchmarks/profile_render.py [--spp 16] [--record-spp 2] [--target brown_wavy] [--threads N] [--mitsuba]
                                        [--rays-only]

1. Preparation of a scene (`warp_hair.prepare`), split into its steps: the segments of the assembly, the
   tubes' frames and boxes, the BVH build (`bvh.build_bvh`), and the rest (tube arrays in leaf order, lights,
   camera, card), on the standard swatch and on the target's fibers.
2. A fit iteration (`optimize.fit`'s loss and gradient at the end of its spp schedule: two gradient passes per
   image) of the target, with its scenes prepared once for the fit and, for comparison, once per
   pass; and the share of preparation in a 48×48 forward render.
3. The standard swatch render at --spp (256×256, depth 16), and its rays: a recording kernel traces paths like
   the integrator (camera ray, a shadow ray toward one light chosen uniformly per vertex, a BSDF-sampled
   continuation with Russian roulette; the swatch has no card) at --record-spp and stores every ray; each
   kind is then traced again alone, on one core (`intersect.intersect` / `occluded`), for its rays per second
   per core. The traversal share of the render is Σ count × time per ray, scaled from --record-spp to --spp;
   the rest of the render's CPU time is shading, sampling and the loop. Rays traced in a batch of one kind, in
   pixel order, are somewhat more coherent than in the render, where each thread alternates kinds: the
   traversal share is a lower bound. With --mitsuba, Mitsuba 3 (Embree) traces the same rays on one thread,
   for its rays per second per core beside ours: how much of the gap to Mitsuba the traversal explains.
   It also renders the swatch in Mitsuba at --spp on the same threads: its whole render's CPU time against its
   rays alone, and against our traversal alone (the bound docs/benchmarks.md draws on the forward goal).

With --rays-only, only part 3.

Timings: wall-clock and CPU seconds (time.process_time: all threads of this process). On a shared machine the
wall times are inflated by other jobs; the CPU times much less.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_hair.geometry.bvh import TRAVERSAL_COST, build_bvh
from warp_hair.geometry.intersect import BVH_WIDTH, intersect_fibers
from warp_hair.geometry.rays import distance, intersect, occluded
from warp_hair.geometry.tubes import MAX_LEAF, segment_boxes, segment_frames
from warp_hair.model.hair_bsdf import hair_sample_incident, hair_value_pdf_at, lobe_setup
from warp_hair.numerics import NO_HIT, rand2, to_local, to_world
from warp_hair.parallel import default_threads
from warp_hair.renderer.camera import generate_ray
from warp_hair.renderer.envmap import env_sample
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.integrator import SceneData
from warp_hair.renderer.light_sampler import choose_light
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import pixel_start, render
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
SWATCH = HERE / "standard_swatch.toml"
TARGETS = HERE.parent / "targets"


class Clock:
    """Wall and CPU seconds of a block."""

    def __enter__(self):
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.wall
        self.cpu = time.process_time() - self.cpu


def preparation(scene) -> list:
    """[(step, wall s, cpu s)] of preparing `scene`, and the whole `prepare` for comparison."""
    rows = []
    with Clock() as c:
        p0, p1, r0, r1, strand, _ = scene.fibers.segments()
    rows.append(("segments of the assembly", c.wall, c.cpu))
    with Clock() as c:
        seg = segment_frames(p0, p1, r0, r1, strand)
    rows.append(("tube frames (mitre planes)", c.wall, c.cpu))
    with Clock() as c:
        lowers, uppers = segment_boxes(seg)
    rows.append(("tube boxes", c.wall, c.cpu))
    with Clock() as c:
        build_bvh(lowers, uppers, max_leaf=MAX_LEAF, width=BVH_WIDTH, traversal_cost=TRAVERSAL_COST)
    rows.append(("BVH build", c.wall, c.cpu))
    with Clock() as c:
        prepare(scene)
    rest = (
        "rest (tube arrays in leaf order, lights, camera, card)",
        c.wall - sum(r[1] for r in rows),
        c.cpu - sum(r[2] for r in rows),
    )
    rows.append(rest)
    rows.append(("whole prepare()", c.wall, c.cpu))
    return rows


@wp.kernel
def record_paths(
    scene: SceneData,
    spp: int,
    seed: int,
    cam_o: wp.array(dtype=wp.vec3),
    cam_d: wp.array(dtype=wp.vec3),
    cont_o: wp.array(dtype=wp.vec3),
    cont_d: wp.array(dtype=wp.vec3),
    shadow_o: wp.array(dtype=wp.vec3),
    shadow_d: wp.array(dtype=wp.vec3),
):
    """Every ray of spp paths per pixel, traced as the integrator traces them (fibers only, no card): slot
    (pixel·spp + s)·max_depth + vertex, a zero direction where a path has no such ray."""
    pixel = wp.tid()
    px, py, rng = pixel_start(scene, pixel, seed)
    num_emitters = scene.num_lights + scene.has_env
    for s in range(spp):
        jitter, rng = rand2(rng)
        o, d = generate_ray(scene.camera, px, py, jitter)
        path = pixel * spp + s
        cam_o[path] = o
        cam_d[path] = d
        throughput = wp.vec3(1.0)
        depth = int(0)
        while depth < scene.max_depth:
            hit = intersect_fibers(scene.surfaces.fibers, o, d, NO_HIT, -1)
            if hit.t >= NO_HIT:
                break
            slot = path * scene.max_depth + depth
            x = hit.tangent
            z = hit.normal
            y = wp.cross(z, x)
            setup = lobe_setup(scene.hair, to_local(-d, x, y, z), hit.h)
            if num_emitters > 0:
                k, _p = choose_light(scene.light_cdf, wp.randf(rng))  # as integrator.sample_ld chooses
                to_light = wp.vec3(0.0)
                if k < scene.num_lights:
                    to_light = scene.lights[k].to_light
                else:
                    u_env, rng = rand2(rng)
                    d_env, pdf_env = env_sample(scene.env, u_env)
                    if pdf_env > 0.0:
                        to_light = d_env
                shadow_o[slot] = hit.position
                shadow_d[slot] = to_light
            sample = hair_sample_incident(setup, wp.vec3(wp.randf(rng), wp.randf(rng), wp.randf(rng)))
            value, pdf = hair_value_pdf_at(setup, sample)
            wi = sample.w
            if pdf <= 0.0:
                break
            throughput = wp.cw_mul(throughput, value / pdf)
            o = hit.position
            d = wp.normalize(to_world(wi, x, y, z))
            cont_o[slot] = o
            cont_d[slot] = d
            depth += 1
            if depth >= scene.rr_depth:
                survive = wp.min(1.0, wp.max(throughput[0], wp.max(throughput[1], throughput[2])))
                if wp.randf(rng) >= survive:
                    break
                throughput = throughput / survive


def recorded_rays(prepared, spp, seed=0) -> dict:
    """{kind: (origins, directions)} of the rays of `spp` paths per pixel."""
    width, height = prepared.resolution
    n = width * height
    slots = n * spp * prepared.scene.render.max_depth
    arrays = [wp.zeros(n * spp, dtype=wp.vec3) for _ in range(2)] + [wp.zeros(slots, dtype=wp.vec3) for _ in range(4)]
    wp.launch(record_paths, dim=n, inputs=[prepared.data, spp, seed, *arrays])
    cam_o, cam_d, cont_o, cont_d, sh_o, sh_d = (a.numpy() for a in arrays)
    out = {"camera": (cam_o, cam_d)}
    for kind, o, d in (("continuation", cont_o, cont_d), ("shadow", sh_o, sh_d)):
        used = np.any(d != 0, axis=1)
        out[kind] = (o[used], d[used])
    return out


def ray_rates(prepared, rays, spp_record, spp) -> list:
    """[(kind, rays in the render at spp, seconds per ray on one core, seconds per ray of the preliminary query)]
    of `recorded_rays(prepared, spp_record)`. The preliminary query is Embree's, which Mitsuba's
    `ray_intersect_preliminary(...).t` times: the closest hit's distance and primitive (`rays.distance`), without
    the hit point and shading frame that `rays.intersect` adds and the render needs; for shadow rays both are
    `rays.occluded`."""
    rows = []
    for kind, (o, d) in rays.items():
        per_ray = []
        for trace in (occluded,) if kind == "shadow" else (intersect, distance):
            trace(prepared.bvh, o[:1000], d[:1000])  # compile / load the kernel outside the timing
            with Clock() as c:
                trace(prepared.bvh, o, d)
            per_ray.append(c.cpu / max(len(o), 1))
        # The full hit, then the preliminary query; a shadow ray's one query is both.
        rows.append((kind, len(o) * spp / spp_record, per_ray[0], per_ray[-1]))
    return rows


def mitsuba_ray_rates(scene, rays) -> dict:
    """{kind: seconds per ray on one core} of Mitsuba 3 (llvm_ad_rgb, Embree) tracing the same recorded rays in
    the same swatch (`linearcurve` over the same vertices, as `render_swatch.py` renders it): closest hits by
    `ray_intersect_preliminary` (no shading frame: traversal and the curve test), shadow rays by `ray_test`;
    or {} without Mitsuba. One Dr.Jit thread, so that the figures compare with ours per core."""
    from mitsuba_peer import import_mitsuba, mitsuba_scene

    mi = import_mitsuba()
    if mi is None:
        return {}
    import drjit as dr

    dr.set_thread_count(1)
    mi_scene = mitsuba_scene(mi, scene, 1)
    out = {}
    for kind, (o, d) in rays.items():

        def trace(o, d, kind=kind):
            ray = mi.Ray3f(
                mi.Point3f(*(o[:, k].astype(np.float32) for k in range(3))),
                mi.Vector3f(*(d[:, k].astype(np.float32) for k in range(3))),
            )
            dr.eval(ray)
            with Clock() as c:
                result = mi_scene.ray_test(ray) if kind == "shadow" else mi_scene.ray_intersect_preliminary(ray).t
                dr.eval(result)
                dr.sync_thread()
            return c.cpu

        trace(o[:1000], d[:1000])  # JIT-compile outside the timing
        out[kind] = trace(o, d) / max(len(o), 1)
    return out


def mitsuba_render(scene, spp, threads) -> tuple:
    """(wall, CPU) seconds of Mitsuba 3's render of `scene` at `spp` on `threads` Dr.Jit threads, after a 1-spp
    render that compiles its kernels (as render_swatch.py times it). Dr.Jit's threads are this process's, so
    process_time counts them."""
    from mitsuba_peer import import_mitsuba, mitsuba_scene

    mi = import_mitsuba()
    import drjit as dr

    dr.set_thread_count(threads)
    mi_scene = mitsuba_scene(mi, scene, spp)
    np.array(mi.render(mi_scene, spp=1, seed=0))
    with Clock() as c:
        np.array(mi.render(mi_scene, spp=spp, seed=0))
    return c.wall, c.cpu


def fit_iteration(target_dir, spp, threads) -> dict:
    """Seconds of a fit iteration's renders (a gradient pass pair per image at spp/2 each), with its scenes
    prepared once and with one preparation per pass, and of the preparation alone."""
    from optimize.target import load_target

    target = load_target(target_dir)
    scenes = [image.scene for image in target.images]
    prepared = [prepare(s) for s in scenes]
    half = max(1, spp // 2)
    for p in prepared:
        render_jacobian(p, spp=1, threads=threads)  # warm the kernels
    out = {}
    for label, inputs in (("prepared once per fit", prepared), ("prepared per pass", scenes)):
        with Clock() as c:
            for s in inputs:
                for seed in (1, 2):
                    render_jacobian(s, spp=half, seed=seed, threads=threads)
        out[label] = (c.wall, c.cpu)
    with Clock() as c:
        for s in scenes:
            prepare(s)
    out["preparation of the images, once"] = (c.wall, c.cpu)
    with Clock() as c:
        render(scenes[0], spp=4, threads=threads)
    out[f"forward render of {target.images[0].name}, 4 spp, with its preparation"] = (c.wall, c.cpu)
    with Clock() as c:
        render(prepared[0], spp=4, threads=threads)
    out[f"forward render of {target.images[0].name}, 4 spp, prepared"] = (c.wall, c.cpu)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel of the swatch render (default 16)")
    parser.add_argument("--record-spp", type=int, default=2, help="paths per pixel recorded for the ray rates")
    parser.add_argument("--target", default="brown_wavy", help="shipped target for the fit iteration")
    parser.add_argument("--fit-spp", type=int, default=16, help="the fit's final spp (FitSettings.spp)")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--mitsuba", action="store_true", help="also time Mitsuba 3 tracing the same rays")
    parser.add_argument("--rays-only", action="store_true", help="only the swatch render and its rays (part 3)")
    args = parser.parse_args()
    threads = args.threads or default_threads()
    wp.init()
    swatch = load_scene(SWATCH)
    target_scene = load_scene(TARGETS / args.target / "scene_front.toml")

    print(f"threads: {threads}; wall and CPU (process_time, all threads) seconds")
    if not args.rays_only:
        preparation_and_fit(args, swatch, target_scene, threads)
    swatch_rays(args, swatch, threads)


def preparation_and_fit(args, swatch, target_scene, threads) -> None:
    """Parts 1 and 2 of the module docstring."""
    for name, scene in (("standard swatch", swatch), (f"{args.target} front", target_scene)):
        prepare(scene)  # warm the imports and caches
        m = len(scene.fibers.segments()[0])
        print(f"\n## Preparation: {name}, {m} segments\n\n| step | wall s | CPU s |\n|---|---:|---:|")
        for step, wall, cpu in preparation(scene):
            print(f"| {step} | {wall:.4f} | {cpu:.4f} |")

    print(
        f"\n## A fit iteration of {args.target} at spp {args.fit_spp} (two passes of {max(1, args.fit_spp // 2)} "
        f"per image)\n\n| what | wall s | CPU s |\n|---|---:|---:|"
    )
    for label, (wall, cpu) in fit_iteration(TARGETS / args.target, args.fit_spp, threads).items():
        print(f"| {label} | {wall:.3f} | {cpu:.3f} |")


def swatch_rays(args, swatch, threads) -> None:
    """Part 3 of the module docstring."""
    prepared = prepare(swatch)
    render(prepared, spp=1, threads=threads)
    with Clock() as c:
        render(prepared, spp=args.spp, threads=threads)
    w, h = swatch.camera.resolution
    print(
        f"\n## Standard swatch {w}×{h}, {args.spp} spp, depth {swatch.render.max_depth}: render {c.wall:.2f} s wall, "
        f"{c.cpu:.2f} s CPU\n\n| rays | count | µs per ray, one core | rays/s per core | CPU s in the render | share |"
        "\n|---|---:|---:|---:|---:|---:|"
    )
    rays = recorded_rays(prepared, args.record_spp)
    rows = ray_rates(prepared, rays, args.record_spp, args.spp)
    traversal = 0.0
    for kind, count, per_ray, _preliminary in rows:
        seconds = count * per_ray
        traversal += seconds
        print(
            f"| {kind} | {count:.3g} | {per_ray * 1e6:.2f} | {1 / per_ray:.3g} | {seconds:.2f} | "
            f"{seconds / c.cpu:.0%} |"
        )
    rest = c.cpu - traversal
    print(f"| shading, sampling, the loop (the rest) | | | | {rest:.2f} | {rest / c.cpu:.0%} |")
    if args.mitsuba:
        theirs = mitsuba_ray_rates(swatch, rays)
        if theirs:
            print(
                "\n## The same rays traced by Mitsuba 3 (Embree, one thread)\n\nBoth preliminary: the closest hit's "
                "distance (and primitive), or occlusion; our full hit adds its point and shading frame.\n\n"
                "| rays | warp-hair µs per ray, full hit | warp-hair µs per ray, preliminary | Mitsuba µs per ray | "
                "ratio (preliminary) | CPU s in our render | at Mitsuba's rate |\n|---|---:|---:|---:|---:|---:|---:|"
            )
            at_theirs = 0.0
            for kind, count, per_ray, preliminary in rows:
                at_theirs += count * theirs[kind]
                print(
                    f"| {kind} | {per_ray * 1e6:.2f} | {preliminary * 1e6:.2f} | {theirs[kind] * 1e6:.2f} | "
                    f"{preliminary / theirs[kind]:.2f} | {count * per_ray:.2f} | {count * theirs[kind]:.2f} |"
                )
            print(
                f"\nOur render at Mitsuba's ray rates: {at_theirs + rest:.2f} s CPU instead of {c.cpu:.2f} s "
                f"(traversal {traversal:.2f} → {at_theirs:.2f} s, the rest {rest:.2f} s unchanged)."
            )
            # The bound on the forward goal: what Mitsuba's whole render costs beside its rays, and our
            # traversal alone (preliminary queries: no hit point, no BSDF) beside that whole render.
            wall, cpu = mitsuba_render(swatch, args.spp, threads)
            ours_preliminary = sum(count * preliminary for _kind, count, _per_ray, preliminary in rows)
            print(
                f"\nMitsuba's whole render of the same swatch at {args.spp} spp on {threads} thread(s): "
                f"{cpu:.2f} s CPU ({wall:.2f} s wall); its rays alone at the rates above {at_theirs:.2f} s, so its "
                f"shading, sampling and loop about {cpu - at_theirs:.2f} s. Our traversal alone, as preliminary "
                f"queries (no hit point, shading or BSDF): {ours_preliminary:.2f} s, {ours_preliminary / cpu:.2f}× "
                "Mitsuba's whole render."
            )


if __name__ == "__main__":
    main()
