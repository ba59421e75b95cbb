"""Mitsuba 3 as a reference renderer: a warp-hair scene as a Mitsuba scene, rendered with `llvm_ad_rgb`.

    from mitsuba_peer import import_mitsuba, mitsuba_scene, time_mitsuba, bspline_control_points
    mi = import_mitsuba()                                     # None, with the reason printed, when not installed
    image = time_mitsuba(mi, mitsuba_scene(mi, scene, spp, shape="bsplinecurve", fibers_file=f), spp, 0, 2, 1)[2]

The `bench` extra (`pip install -e ".[bench]"`); its LLVM back end needs libLLVM (`apt-get install libllvm19`):
DRJIT_LIBLLVM_PATH is set to the system's libLLVM-19 when unset (it must be set before the import). The hair is
the look as `warp_hair.export.mitsuba` writes it. Use `bsplinecurve` over `bspline_control_points(fibers)` for
anything but fibers along y (docs/MODEL.md, "The peers as references").
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.scene import DirectionalLight, EnvironmentLight

LIBLLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM-19.so")


def import_mitsuba():
    """The mitsuba module with the llvm_ad_rgb variant set, or None (with the reason printed)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and LIBLLVM.is_file():
        os.environ["DRJIT_LIBLLVM_PATH"] = str(LIBLLVM)
    try:
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
    except ImportError as error:
        print(f"Mitsuba comparison skipped: {error}. Enable it with `pip install mitsuba` (and libLLVM: "
              "apt-get install libllvm19, or DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so).")
        return None
    return mi


def mitsuba_scene(mi, scene, spp, shape="linearcurve", fibers_file=None):
    """The warp-hair `scene` as a Mitsuba 3 scene. Only what the comparison needs is translated: an
    orthographic or perspective camera, directional lights, a constant environment, fibers from a file
    (`fibers_file`, default the scene's) as `shape`, the hair as warp_hair.export.mitsuba writes it."""
    from warp_hair.export.mitsuba import bsdf_dict

    cam = scene.camera
    width, height = cam.resolution
    T = mi.ScalarTransform4f
    to_world = T().look_at(origin=cam.origin, target=cam.target, up=cam.up)
    if cam.type == "orthographic":
        # Mitsuba's orthographic sensor sees [-1, 1] along the camera's x (and y·H/W): scale by half the width.
        sensor = {"type": "orthographic", "to_world": to_world @ T().scale([0.5 * cam.width, 0.5 * cam.width, 1])}
    else:
        sensor = {"type": "perspective", "to_world": to_world, "fov": cam.fov, "fov_axis": "x"}
    sensor["film"] = {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                      "pixel_format": "rgb"}
    sensor["sampler"] = {"type": "independent", "sample_count": spp}

    fibers_file = fibers_file or scene.source["fibers"].get("file")  # absolute: the loader resolved it
    if fibers_file is None or scene.card is not None:
        raise ValueError("the Mitsuba comparison needs fibers from a file (linearcurve) and no backing card")
    hair = scene.hair
    if hair.r_roughness_scale != 1.0:
        raise ValueError("Mitsuba's hair BSDF has no R-roughness scale; set r_roughness_scale = 1")
    bsdf = bsdf_dict(hair)  # scale_tilt = −α: Mitsuba rotates the lobes opposite to the physical tilt
    result = {
        "type": "scene",
        "sensor": sensor,
        # Mitsuba counts path segments (max_depth 1: emitters seen directly, 2: direct lighting); ours counts
        # scattering vertices (1: direct lighting), so our 16 are its 17. Both start Russian roulette once
        # rr_depth vertices are done (Mitsuba: depth >= rr_depth after its increment).
        "integrator": {"type": "path", "max_depth": scene.render.max_depth + 1, "rr_depth": scene.render.rr_depth},
        "fibers": {"type": shape, "filename": str(fibers_file), "bsdf": bsdf},
    }
    for k, light in enumerate(scene.lights):
        if isinstance(light, DirectionalLight):
            # Both take the direction the light travels, and the irradiance on a surface facing the light.
            result[f"light{k}"] = {"type": "directional", "direction": list(light.direction),
                                   "irradiance": {"type": "rgb", "value": list(light.irradiance)}}
        elif isinstance(light, EnvironmentLight) and light.image is None:
            result[f"light{k}"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(light.radiance)}}
        else:
            raise ValueError("the Mitsuba comparison does not translate environment maps")
    return mi.load_dict(result)


def time_mitsuba(mi, mi_scene, spp, seed, threads, repeat):
    """(warm-up seconds, best seconds, image). Dr.Jit traces and compiles its kernels on the first render
    (a 1-spp render compiles the same kernels), so the timed renders are the later ones. Converting the result
    to NumPy inside the timed region waits for the lazily evaluated image."""
    import drjit as dr

    dr.set_thread_count(threads)
    start = time.perf_counter()
    np.array(mi.render(mi_scene, spp=1, seed=seed))
    warmup = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        image = np.array(mi.render(mi_scene, spp=spp, seed=seed), dtype=np.float32)
        best = min(best, time.perf_counter() - start)
    return warmup, best, image


def bspline_control_points(fibers):
    """The strands with one control point added at each end, mirrored through the end vertex (2·p0 − p1):
    a uniform cubic B-spline over the vertices alone stops short of the end vertices by about a segment, and
    with these it starts and ends exactly at them, so that Mitsuba's `bsplinecurve` spans the same fibers."""
    strands = []
    for k in range(fibers.num_strands):
        points, radii = fibers.strand(k)
        points = np.concatenate([[2 * points[0] - points[1]], points, [2 * points[-1] - points[-2]]])
        strands.append((points, np.concatenate([radii[:1], radii, radii[-1:]])))
    return FiberAssembly.from_strands(strands)
