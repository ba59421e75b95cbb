"""Mitsuba 3 as a reference renderer: a warp-hair scene as a Mitsuba scene, rendered with `llvm_ad_rgb`.

    from mitsuba_peer import import_mitsuba, mitsuba_scene, time_mitsuba, bspline_control_points
    mi = import_mitsuba()                                     # None, with the reason printed, when not installed
    scene_mi = mitsuba_scene(mi, scene, spp, shape="bsplinecurve", fibers_file=f, sampler="corrected")
    image = time_mitsuba(mi, scene_mi, spp, 0, 2, 1)[2]

The `bench` extra (`pip install -e ".[bench]"`); its LLVM back end needs libLLVM (`apt-get install libllvm19`):
DRJIT_LIBLLVM_PATH is set to the system's libLLVM-19 when unset (it must be set before the import). The hair is
the look as `warp_hair.export.mitsuba` writes it. Use `bsplinecurve` over `bspline_control_points(fibers)` for
anything but fibers along y (docs/MODEL.md, "The peers as references"). Its curves report only the hits where a
ray enters them, so strands that pass through each other render as warp-hair's default `[render]
interpenetration = "enter"` (docs/scenes.md, "Interpenetrating strands").

Mitsuba's hair sampler has a bug, measured by `benchmarks/mitsuba_residual_lobe.py`: `Hair::sample`
(src/bsdfs/hair.cpp, 3.9.1 and its main branch) tilts sin/cos θ per lobe only for p < P_MAX and leaves both at 0
for the residual lobe p = 3, so every sample it draws from that lobe has sin θ = 0: it leaves in the fiber's
normal plane, wherever M_3 puts it. `eval` and `pdf` are right, so direct lighting is too, and the weight
eval/pdf is formed at that wrong direction. Light hair, whose residual lobe carries the most, renders 2% brighter
front-lit on a draped swatch. `sampler="corrected"` renders with `CorrectedHair`, Mitsuba's own `hair` BSDF
(its eval, pdf and every other lobe's sampling) with the residual lobe's θ drawn as pbrt-v4 draws it
(`HairBxDF::Sample_f`: the untilted θ_o for p = 3); `sampler="stock"` is Mitsuba as shipped (the speed
benchmarks use it).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.renderer.light_sampler import selection_probabilities
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
        print(
            f"Mitsuba comparison skipped: {error}. Enable it with `pip install mitsuba` (and libLLVM: "
            "apt-get install libllvm19, or DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so)."
        )
        return None
    return mi


SAMPLERS = ("stock", "corrected")
# Mitsuba's pixel sample generators (its `sampler` plugins) that render with any power-of-four spp unrounded.
SENSOR_SAMPLERS = ("independent", "multijitter", "ldsampler")


def mitsuba_scene(
    mi,
    scene,
    spp,
    shape="linearcurve",
    fibers_file=None,
    sampler="stock",
    sensor_sampler="independent",
    light_weights=False,
):
    """The warp-hair `scene` as a Mitsuba 3 scene. Only what the comparison needs is translated: an
    orthographic or perspective camera, directional lights, a constant environment, the backing card, fibers
    from a file (`fibers_file`, default the scene's) as `shape`, the hair as warp_hair.export.mitsuba writes it, sampled
    by Mitsuba's own `hair` (`sampler="stock"`) or with its residual lobe corrected (`"corrected"`). The
    sensor draws its samples with `sensor_sampler` (one of SENSOR_SAMPLERS). Its emitters are chosen uniformly, as
    Mitsuba does by default, or with `light_weights` by the weights warp-hair chooses its lights by
    (warp_hair.renderer.light_sampler)."""
    from warp_hair.export.mitsuba import bsdf_dict

    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, not {sampler!r}")
    if sensor_sampler not in SENSOR_SAMPLERS:
        raise ValueError(f"sensor_sampler must be one of {SENSOR_SAMPLERS}, not {sensor_sampler!r}")

    cam = scene.camera
    width, height = cam.resolution
    T = mi.ScalarTransform4f
    to_world = T().look_at(origin=cam.origin, target=cam.target, up=cam.up)
    if cam.type == "orthographic":
        # Mitsuba's orthographic sensor sees [-1, 1] along the camera's x (and y·H/W): scale by half the width.
        sensor = {"type": "orthographic", "to_world": to_world @ T().scale([0.5 * cam.width, 0.5 * cam.width, 1])}
    else:
        sensor = {"type": "perspective", "to_world": to_world, "fov": cam.fov, "fov_axis": "x"}
    sensor["film"] = {
        "type": "hdrfilm",
        "width": width,
        "height": height,
        "rfilter": {"type": "box"},
        "pixel_format": "rgb",
    }
    sensor["sampler"] = {"type": sensor_sampler, "sample_count": spp}

    fibers_file = fibers_file or scene.source["fibers"].get("file")  # absolute: the loader resolved it
    if fibers_file is None:
        raise ValueError("the Mitsuba comparison needs fibers from a file (`fibers_file`, or the scene's)")
    hair = scene.hair
    if hair.r_roughness_scale != 1.0:
        raise ValueError("Mitsuba's hair BSDF has no R-roughness scale; set r_roughness_scale = 1")
    bsdf = bsdf_dict(hair)  # scale_tilt = −α: Mitsuba rotates the lobes opposite to the physical tilt
    if sampler == "corrected":
        bsdf = corrected_hair(mi, bsdf)
    result = {
        "type": "scene",
        "sensor": sensor,
        # Mitsuba counts path segments (max_depth 1: emitters seen directly, 2: direct lighting); ours counts
        # scattering vertices (1: direct lighting), so our 16 are its 17. Both start Russian roulette once
        # rr_depth vertices are done (Mitsuba: depth >= rr_depth after its increment).
        "integrator": {"type": "path", "max_depth": scene.render.max_depth + 1, "rr_depth": scene.render.rr_depth},
        "fibers": {"type": shape, "filename": str(fibers_file), "bsdf": bsdf},
    }
    if scene.card is not None:
        result["card"] = _card(mi, scene)
    # warp-hair's emitters in its order (prepare.py): the directional lights, then the environment.
    directional = [light for light in scene.lights if isinstance(light, DirectionalLight)]
    environment = next((light for light in scene.lights if isinstance(light, EnvironmentLight)), None)
    emitters = directional + ([environment] if environment is not None else [])
    probabilities = selection_probabilities(directional, environment)
    for k, light in enumerate(scene.lights):
        if isinstance(light, DirectionalLight):
            # Both take the direction the light travels, and the irradiance on a surface facing the light.
            result[f"light{k}"] = {
                "type": "directional",
                "direction": list(light.direction),
                "irradiance": {"type": "rgb", "value": list(light.irradiance)},
            }
        elif isinstance(light, EnvironmentLight) and light.image is None:
            result[f"light{k}"] = {"type": "constant", "radiance": {"type": "rgb", "value": list(light.radiance)}}
        else:
            raise ValueError("the Mitsuba comparison does not translate environment maps")
        if light_weights:
            # Mitsuba's own emitter `sampling_weight`, set to warp-hair's probability of choosing the light.
            position = next(i for i, emitter in enumerate(emitters) if emitter is light)
            result[f"light{k}"]["sampling_weight"] = float(probabilities[position])
    return mi.load_dict(result)


def _card(mi, scene):
    """The backing card (warp_hair.geometry.card: a plane facing the camera behind the fibers, two-sided
    Lambertian) as a two-sided diffuse `rectangle` 10⁴ scene units across, at the same plane."""
    from warp_hair.geometry.card import card_plane

    points = np.asarray(scene.fibers.points, dtype=np.float64)
    point, normal = card_plane(scene.card, scene.camera, (points.min(axis=0), points.max(axis=0)))
    up = np.array([0.0, 1.0, 0.0]) if abs(normal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    T = mi.ScalarTransform4f
    to_world = T().look_at(origin=point, target=point + normal, up=up) @ T().scale([5e3, 5e3, 1.0])
    diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(scene.card.albedo)}}
    return {"type": "rectangle", "to_world": to_world, "bsdf": {"type": "twosided", "bsdf": diffuse}}


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


_CORRECTED_HAIR = "warp_hair_corrected_hair"
_REGISTERED = set()


def corrected_hair(mi, hair_dict):
    """A `load_dict` entry for `CorrectedHair` around Mitsuba's `hair` BSDF given by `hair_dict`."""
    if _CORRECTED_HAIR not in _REGISTERED:
        mi.register_bsdf(_CORRECTED_HAIR, _corrected_hair_class(mi))
        _REGISTERED.add(_CORRECTED_HAIR)
    return {"type": _CORRECTED_HAIR, "hair": hair_dict}


def _corrected_hair_class(mi):
    """Mitsuba's `hair` with the residual lobe's longitudinal sample drawn right (module docstring).

    Mitsuba's `sample` returns, for the residual lobe and only for it, a direction with wo.y (sin θ) exactly 0;
    its azimuth is already right (uniform). For those samples θ is drawn again from the same two numbers
    Mitsuba used (sample2: cos θ of the cone about the untilted θ_o, then the rotation), as pbrt-v4 draws it,
    and the value and pdf are Mitsuba's own `eval_pdf` at the new direction. Another lobe's sample lands on
    wo.y == 0 exactly with probability zero."""
    import drjit as dr

    from warp_hair.model.params import lobe_variances

    class CorrectedHair(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.inner = props["hair"]  # Mitsuba instantiates the nested `hair` dictionary
            beta_m = float(mi.traverse(self.inner)["longitudinal_roughness"][0])
            self.v_residual = float(lobe_variances(beta_m)[3])
            self.m_flags = self.inner.flags()
            self.m_components = [self.inner.flags()]

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs, weight = self.inner.sample(ctx, si, sample1, sample2, active)
            residual = bs.wo.y == 0
            v = self.v_residual
            cos_cone = dr.clip(1 + v * dr.log(sample2.x + (1 - sample2.x) * dr.exp(-2 / v)), -1, 1)
            sin_cone = dr.safe_sqrt(1 - cos_cone * cos_cone)
            sin_i = si.wi.y
            cos_i = dr.safe_sqrt(1 - sin_i * sin_i)
            sin_o = -cos_cone * sin_i + sin_cone * dr.cos(2 * dr.pi * sample2.y) * cos_i
            cos_o = dr.safe_sqrt(1 - sin_o * sin_o)
            wo = mi.Vector3f(cos_o * bs.wo.x, sin_o, cos_o * bs.wo.z)  # bs.wo.x, .z: cos φ, sin φ
            value, pdf = self.inner.eval_pdf(ctx, si, wo, active & residual)
            bs.wo = dr.select(residual, wo, bs.wo)
            bs.pdf = dr.select(residual, pdf, bs.pdf)
            weight = dr.select(residual, dr.select(pdf > 0, value / pdf, 0), weight)
            return bs, weight

        def eval(self, ctx, si, wo, active=True):
            return self.inner.eval(ctx, si, wo, active)

        def pdf(self, ctx, si, wo, active=True):
            return self.inner.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.inner.eval_pdf(ctx, si, wo, active)

        def traverse(self, callback):
            self.inner.traverse(callback)

        def to_string(self):
            return f"CorrectedHair[{self.inner}]"

    return CorrectedHair
