"""Benchmark: render a look exported by warp_hair.export in Mitsuba 3 and in Blender Cycles, and compare with
warp-hair on the same draped swatch (benchmarks/draped_swatch.toml, alpha = 0).

    python benchmarks/export_roundtrip.py [--spp 128] [--cycles-spp 128] [--threads N] [--out DIR] [--no-cycles]
                                          [--alpha DEG]

Prints each renderer's mean RGB and the ratio to warp-hair's, with its Monte Carlo standard error (each renderer
renders two independent halves of the samples, seeds s and s + 1; the halves' per-pixel differences give the
error of the mean); the target is agreement within 2% in the means.
Mitsuba (the `bench` extra, llvm_ad_rgb; libLLVM from `apt-get install libllvm19`) renders the exported
`hair` BSDF dictionary on `bsplinecurve` with the polylines' vertices as control points (its `linearcurve`
hands the BSDF a wrong frame, MODEL.md). Cycles (the `blender` extra, bpy 4.5) runs the exported bpy script to
build its Principled Hair BSDF and renders Catmull-Rom THICK curves through the same vertices, with the settings
that make it comparable: box pixel filter of width 1, no glossy filter, no clamping, light threshold 0, no
denoising or adaptive sampling, 128 bounces of every kind, the sun's strength as irradiance and the world colour
as radiance. Blender runs in a child process (bpy brings its own libraries). Either renderer is skipped, with
the reason, when it is not installed. Timings are not the point here; the machine may be shared.

`--alpha DEG` checks the tilt's sign instead, with Cycles only (Mitsuba's curves flip the tangent with the side
of the fiber hit): it prints where the highlight band lies (the centroid row of the brightest fifth of the row
profile, row 0 at the tips) in warp-hair at +α and −α and in Cycles with the exported Offset.
"""

from __future__ import annotations

import argparse
import copy
import importlib.metadata
import importlib.util
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from warp_hair.export import export
from warp_hair.fibers import save_fibers
from warp_hair.io import read_exr, write_exr, write_png
from warp_hair.render import render
from warp_hair.scene import DirectionalLight, EnvironmentLight, load_scene

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from render_swatch import import_mitsuba, mitsuba_scene  # noqa: E402

SCENE = HERE / "draped_swatch.toml"
TOLERANCE = 0.02


def render_mitsuba(mi, scene, spp, seed, fibers_txt):
    mi_scene = mitsuba_scene(mi, scene, spp, shape="bsplinecurve", fibers_file=fibers_txt)
    return np.array(mi.render(mi_scene, spp=spp, seed=seed), dtype=np.float32)


def cycles_job(scene, spp, seed, workdir):
    """A JSON job for the Blender child: the scene in plain numbers, the exported script, the output file."""
    lights = []
    for light in scene.lights:
        if isinstance(light, DirectionalLight):
            lights.append({"type": "sun", "direction": list(light.direction), "irradiance": list(light.irradiance)})
        elif isinstance(light, EnvironmentLight) and light.image is None:
            lights.append({"type": "world", "radiance": list(light.radiance)})
        else:
            raise ValueError("the Cycles comparison translates directional lights and constant environments only")
    forward, right, up = scene.camera.frame()
    np.save(workdir / "points.npy", scene.fibers.points)
    np.save(workdir / "radii.npy", scene.fibers.radii)
    np.save(workdir / "counts.npy", scene.fibers.vertex_counts)
    export(scene.hair, "cycles", workdir / "hair_cycles.py")
    job = {
        "camera": {"origin": list(scene.camera.origin), "right": right.tolist(), "up": up.tolist(),
                   "forward": forward.tolist(), "width": scene.camera.width, "resolution": list(scene.camera.resolution)},
        "lights": lights, "spp": spp, "seed": seed, "workdir": str(workdir),
        "script": str(workdir / "hair_cycles.py"), "output": str(workdir / "cycles.exr"),
    }
    (workdir / "job.json").write_text(json.dumps(job))
    return workdir / "job.json"


def cycles_child(job_path):
    """Runs inside the Blender child process: build the scene, run the exported script, render to EXR."""
    import bpy
    import mathutils

    job = json.loads(Path(job_path).read_text())
    work = Path(job["workdir"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples, c.seed = job["spp"], job["seed"]
    c.use_adaptive_sampling = c.use_denoising = False
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0
    c.light_sampling_threshold = 0.0
    for bounces in ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces", "transparent_max_bounces"):
        setattr(c, bounces, 128)
    c.pixel_filter_type, c.filter_width = "BOX", 1.0
    scene.cycles_curves.shape = "THICK"
    scene.view_settings.view_transform = "Standard"
    width, height = job["camera"]["resolution"]
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = job["output"]

    cam = job["camera"]
    camera = bpy.data.cameras.new("camera")
    camera.type, camera.ortho_scale, camera.sensor_fit = "ORTHO", cam["width"], "HORIZONTAL"
    camera.clip_start, camera.clip_end = 1e-3, 1e3
    camera_object = bpy.data.objects.new("camera", camera)
    # Blender cameras look down their local −z with +y up.
    basis = mathutils.Matrix([cam["right"], cam["up"], [-x for x in cam["forward"]]]).transposed()
    camera_object.matrix_world = mathutils.Matrix.Translation(cam["origin"]) @ basis.to_4x4()
    scene.collection.objects.link(camera_object)
    scene.camera = camera_object

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    scene.world = world
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    for light in job["lights"]:
        if light["type"] == "world":
            world.node_tree.nodes["Background"].inputs["Color"].default_value = (*light["radiance"], 1.0)
            world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
            continue
        sun = bpy.data.lights.new("sun", "SUN")
        strength = max(light["irradiance"])
        sun.energy, sun.color, sun.angle = strength, [x / strength for x in light["irradiance"]], 0.0
        sun_object = bpy.data.objects.new("sun", sun)
        # A sun shines along its local −z.
        direction = mathutils.Vector(light["direction"]).normalized()
        sun_object.rotation_euler = (-direction).to_track_quat("Z", "Y").to_euler()
        scene.collection.objects.link(sun_object)

    counts = np.load(work / "counts.npy")
    curves = bpy.data.hair_curves.new("fibers")
    curves.add_curves([int(n) for n in counts])  # new curves are Catmull-Rom: through their points
    curves.position_data.foreach_set("vector", np.load(work / "points.npy").astype(np.float32).ravel())
    radius = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT", "POINT")
    radius.data.foreach_set("value", np.load(work / "radii.npy").astype(np.float32))
    hair_object = bpy.data.objects.new("fibers", curves)
    scene.collection.objects.link(hair_object)

    import runpy

    material = runpy.run_path(job["script"])["make_material"]()
    curves.materials.append(material)
    bpy.ops.render.render(write_still=True)


def render_cycles(scene, spp, seed, workdir):
    if importlib.util.find_spec("bpy") is None:
        print("Cycles comparison skipped: no bpy module. Enable it with `pip install -e \".[blender]\"` (bpy 4.5, "
              "Python 3.11).")
        return None
    job = cycles_job(scene, spp, seed, workdir)
    result = subprocess.run([sys.executable, __file__, "--cycles-job", str(job)], capture_output=True, text=True)
    if result.returncode != 0:
        print(f"Cycles render failed:\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}")
        return None
    image, _ = read_exr(workdir / "cycles.exr")
    return image


def fmt(values, spec=".4f"):
    return "(" + ", ".join(format(v, spec) for v in values) + ")"


def mean_and_error(halves):
    """(image, mean RGB, standard error of the mean RGB) from two independent renders of half the samples."""
    a, b = halves
    n = a.shape[0] * a.shape[1]
    return 0.5 * (a + b), 0.5 * (a + b).mean(axis=(0, 1)), np.sqrt(((a - b) ** 2).sum(axis=(0, 1))) / (2 * n)


def report(name, ours, theirs):
    """Print the renderer's mean RGB and its ratio to ours (± 1σ); return whether every channel is within
    TOLERANCE."""
    (_, mean_ours, error_ours), (_, mean_theirs, error_theirs) = ours, theirs
    ratio = mean_theirs / mean_ours
    error = ratio * np.hypot(error_ours / mean_ours, error_theirs / mean_theirs)
    ok = bool(np.all(np.abs(ratio - 1) <= TOLERANCE))
    print(f"{name:14s} mean RGB {fmt(mean_theirs)} ± {fmt(error_theirs)}   ratio to warp-hair {fmt(ratio)} "
          f"± {fmt(error)}   {'within' if ok else 'OUTSIDE'} {TOLERANCE:.0%}")
    return ok


def highlight_row(image):
    """The centroid row of the brightest fifth of the rows (mean luminance across each row)."""
    profile = image.mean(axis=(1, 2))
    bright = profile >= np.quantile(profile, 0.8)
    rows = np.arange(len(profile))
    return float(np.sum(rows[bright] * profile[bright]) / np.sum(profile[bright]))


def tilt_check(scene, args):
    seed = scene.render.seed
    print(f"tilt check at alpha = {scene.hair.alpha:g} deg (Cycles only; row 0 holds the tips, the roots are at the "
          "bottom)")
    for alpha in (scene.hair.alpha, -scene.hair.alpha):
        image = render(scene_with_alpha(scene, alpha), spp=args.spp, seed=seed, threads=args.threads)
        print(f"warp-hair alpha {alpha:+g}: highlight row {highlight_row(image):.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        cycles = render_cycles(scene, args.cycles_spp, seed, Path(tmp))
    if cycles is not None:
        print(f"Cycles Offset {math.radians(scene.hair.alpha):+.5f} rad: highlight row {highlight_row(cycles):.2f}")
    return 0


def scene_with_alpha(scene, alpha):
    scene = copy.copy(scene)
    scene.hair = scene.hair.replace(alpha=alpha)
    return scene


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=128, help="samples per pixel for warp-hair and Mitsuba")
    parser.add_argument("--cycles-spp", type=int, default=128)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--out", type=Path, default=HERE / "out" / "export_roundtrip")
    parser.add_argument("--no-cycles", action="store_true")
    parser.add_argument("--alpha", type=float, help="check the tilt's sign at this alpha (degrees) against Cycles")
    parser.add_argument("--cycles-job", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.cycles_job is not None:
        return cycles_child(args.cycles_job)

    scene = load_scene(SCENE)
    if args.alpha is not None:
        return tilt_check(scene_with_alpha(scene, args.alpha), args)
    seed = scene.render.seed
    width, height = scene.camera.resolution
    print(f"{SCENE.name}: {width}x{height}, {scene.fibers.num_strands} fibers, look {scene.hair.to_dict()}; "
          f"{args.spp} spp (warp-hair, Mitsuba), {args.cycles_spp} spp (Cycles), in two halves each")
    args.out.mkdir(parents=True, exist_ok=True)
    half = lambda spp: max(1, spp // 2)  # noqa: E731
    ours = mean_and_error([render(scene, spp=half(args.spp), seed=seed + k, threads=args.threads) for k in (0, 1)])
    print(f"{'warp-hair':14s} mean RGB {fmt(ours[1])} ± {fmt(ours[2])}")
    write_exr(args.out / "warp_hair.exr", ours[0])
    images, agree = [ours[0]], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fibers_txt = tmp / "fibers.txt"
        save_fibers(scene.fibers, fibers_txt)
        # Mitsuba's curve loader takes no comment line.
        fibers_txt.write_text(fibers_txt.read_text().split("\n", 1)[1])
        mi = import_mitsuba()
        if mi is not None:
            mitsuba = mean_and_error([render_mitsuba(mi, scene, half(args.spp), seed + k, fibers_txt) for k in (0, 1)])
            agree.append(report(f"Mitsuba {mi.__version__}", ours, mitsuba))
            write_exr(args.out / "mitsuba.exr", mitsuba[0])
            images.append(mitsuba[0])
        if not args.no_cycles:
            halves = [render_cycles(scene, half(args.cycles_spp), seed + k, tmp) for k in (0, 1)]
            if all(h is not None for h in halves):
                cycles = mean_and_error(halves)
                agree.append(report(f"Cycles {importlib.metadata.version('bpy')}", ours, cycles))
                write_exr(args.out / "cycles.exr", cycles[0])
                images.append(cycles[0])
    write_png(args.out / "side_by_side.png", np.concatenate(images, axis=1))
    print(f"images in {args.out} (side_by_side.png: warp-hair | Mitsuba | Cycles)")
    return 0 if all(agree) else 1

if __name__ == "__main__":
    sys.exit(main())
