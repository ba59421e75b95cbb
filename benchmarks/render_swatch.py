"""Benchmark: time warp-hair on the standard swatch and, where Mitsuba 3 is installed, render the same scene
with it in the same run and compare speed and images.

    python benchmarks/render_swatch.py [--spp 64] [--threads N] [--repeat 1] [--out DIR]

Mitsuba is an optional extra (`pip install mitsuba`); without it the comparison is skipped. Its LLVM back end
needs libLLVM: DRJIT_LIBLLVM_PATH is set to the system's libLLVM-19 when unset (it must be set before the
import). Timings are wall-clock seconds on a shared machine: other jobs running at the same time inflate them.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from warp_hair.io import write_exr, write_png
from warp_hair.parallel import default_threads
from warp_hair.render import render
from warp_hair.scene import DirectionalLight, EnvironmentLight, load_scene

HERE = Path(__file__).resolve().parent
SCENE = HERE / "standard_swatch.toml"
LIBLLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
# Mean radiance differing by more than this (relative, any channel) is reported as a disagreement. At 64 spp
# the noise in the image mean is far below it.
AGREEMENT_TOLERANCE = 0.03
# Side of the pixel blocks compared after averaging, to catch a moved or mirrored image with the same mean.
BLOCK = 16


def time_ours(scene, spp, threads, repeat):
    """(warm-up seconds, best seconds, image). The 1-spp warm-up compiles (or loads) the Warp kernels.
    The timed render includes building the BVH and light tables, as every call to `render` does."""
    start = time.perf_counter()
    render(scene, spp=1, threads=threads)
    warmup = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        image = render(scene, spp=spp, threads=threads)
        best = min(best, time.perf_counter() - start)
    return warmup, best, image


def import_mitsuba():
    """The mitsuba module with the llvm_ad_rgb variant set, or None (with the reason printed)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and LIBLLVM.is_file():
        os.environ["DRJIT_LIBLLVM_PATH"] = str(LIBLLVM)
    try:
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
    except ImportError as error:
        print(f"Mitsuba comparison skipped: {error}. Enable it with `pip install mitsuba` "
              "(and libLLVM, e.g. apt-get install libllvm19, or DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so).")
        return None
    return mi


def mitsuba_scene(mi, scene, spp):
    """The warp-hair `scene` as a Mitsuba 3 scene dict. Only what the comparison needs is translated: an
    orthographic or perspective camera, directional lights, a constant environment, fibers from a file."""
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

    if scene.card is not None:
        raise ValueError("the Mitsuba comparison does not translate the backing card")
    fibers_file = scene.source["fibers"].get("file")  # absolute: the loader resolved it
    if fibers_file is None:
        raise ValueError("the Mitsuba comparison needs fibers from a file (linearcurve), not a generator")
    hair = scene.hair
    if hair.r_roughness_scale != 1.0:
        raise ValueError("Mitsuba's hair BSDF has no R-roughness scale; set r_roughness_scale = 1")
    bsdf = {
        "type": "hair",
        "sigma_a": {"type": "rgb", "value": [float(c) for c in hair.sigma_a]},  # per unit radius in both
        # Ours clamps roughness at 0.01 (warp_hair.params.BETA_FLOOR); Mitsuba does not.
        "longitudinal_roughness": max(hair.beta_m, 0.01),
        "azimuthal_roughness": max(hair.beta_n, 0.01),
        "scale_tilt": hair.alpha,  # degrees in both
        # Mitsuba's eta is int_ior / ext_ior, and ext_ior defaults to air (1.000277): pin it to 1.
        "int_ior": hair.eta,
        "ext_ior": 1.0,
    }
    result = {
        "type": "scene",
        "sensor": sensor,
        # Mitsuba counts path segments (max_depth 1: emitters seen directly, 2: direct lighting); ours counts
        # scattering vertices (1: direct lighting). Our 16 vertices are Mitsuba's 17 segments. Both start
        # Russian roulette after the same number of vertices (Mitsuba: depth >= rr_depth after the increment).
        "integrator": {"type": "path", "max_depth": scene.render.max_depth + 1, "rr_depth": scene.render.rr_depth},
        "fibers": {"type": "linearcurve", "filename": fibers_file, "bsdf": bsdf},
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


def time_mitsuba(mi, scene, spp, threads, repeat):
    """(warm-up seconds, best seconds, image). Dr.Jit traces and compiles its kernels on the first render
    (a 1-spp render compiles the same kernels), so the timed renders are the later ones. Converting the result
    to NumPy inside the timed region waits for the lazily evaluated image."""
    import drjit as dr

    dr.set_thread_count(threads)
    mi_scene = mitsuba_scene(mi, scene, spp)
    seed = scene.render.seed
    start = time.perf_counter()
    np.array(mi.render(mi_scene, spp=1, seed=seed))
    warmup = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        image = np.array(mi.render(mi_scene, spp=spp, seed=seed), dtype=np.float32)
        best = min(best, time.perf_counter() - start)
    return warmup, best, image


def compare(ours, theirs):
    """Print how far apart the two images are; return whether they agree within AGREEMENT_TOLERANCE."""
    mean_ours, mean_theirs = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
    relative = mean_ours / mean_theirs - 1.0
    print(f"mean RGB   warp-hair {fmt(mean_ours)}   Mitsuba {fmt(mean_theirs)}")
    print(f"relative difference of the means (ours/Mitsuba - 1): {fmt(relative, '+.2%')}")
    h, w = (ours.shape[0] // BLOCK) * BLOCK, (ours.shape[1] // BLOCK) * BLOCK

    def blocks(image):
        return image[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).mean(axis=(1, 3))

    block_rms = np.sqrt(np.mean((blocks(ours) / blocks(theirs) - 1.0) ** 2))
    print(f"RMS relative difference of {BLOCK}x{BLOCK}-pixel block means: {block_rms:.2%}")
    agree = bool(np.all(np.abs(relative) <= AGREEMENT_TOLERANCE))
    if not agree:
        print(f"WARNING: the images disagree by more than {AGREEMENT_TOLERANCE:.0%} in the mean; see the images.")
    return agree


def fmt(values, spec=".4f"):
    return "(" + ", ".join(format(v, spec) for v in values) + ")"


def write_images(out, ours, theirs):
    out.mkdir(parents=True, exist_ok=True)
    for name, image in (("warp_hair", ours), ("mitsuba", theirs)):
        if image is not None:
            write_exr(out / f"{name}.exr", image)
            write_png(out / f"{name}.png", image)
    if theirs is not None:
        # Left to right: warp-hair, Mitsuba, 4 × |difference|.
        write_png(out / "side_by_side.png", np.concatenate([ours, theirs, 4.0 * np.abs(ours - theirs)], axis=1))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--threads", type=int, default=None, help="default: every core this process may use")
    parser.add_argument("--repeat", type=int, default=1, help="timed renders; the best is reported")
    parser.add_argument("--out", type=Path, default=HERE / "out")
    args = parser.parse_args(argv)
    threads = args.threads or default_threads()

    scene = load_scene(SCENE)
    width, height = scene.camera.resolution
    paths = width * height * args.spp
    print(f"{SCENE.name}: {width}x{height}, {args.spp} spp, max depth {scene.render.max_depth}, "
          f"{scene.fibers.num_strands} fibers")
    print(f"machine: {os.cpu_count()} cores; threads used: {threads}")

    warmup, seconds, ours = time_ours(scene, args.spp, threads, args.repeat)
    print(f"warp-hair: warm-up (1 spp, kernel compile/load) {warmup:.2f} s; render {seconds:.2f} s "
          f"(best of {args.repeat}) = {paths / seconds / 1e6:.3f} M camera paths/s")

    theirs = None
    mi = import_mitsuba()
    if mi is not None:
        mi_warmup, mi_seconds, theirs = time_mitsuba(mi, scene, args.spp, threads, args.repeat)
        print(f"Mitsuba {mi.__version__} ({mi.variant()}): warm-up (1 spp, JIT compile) {mi_warmup:.2f} s; "
              f"render {mi_seconds:.2f} s (best of {args.repeat}) = {paths / mi_seconds / 1e6:.3f} M camera paths/s")
        print(f"time ratio warp-hair / Mitsuba: {seconds / mi_seconds:.2f}")
        compare(ours, theirs)

    write_images(args.out, ours, theirs)
    print(f"images: {args.out}/" + ("{warp_hair,mitsuba}.{exr,png}, side_by_side.png" if theirs is not None
                                    else "warp_hair.{exr,png}"))


if __name__ == "__main__":
    main()
