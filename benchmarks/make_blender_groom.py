"""A groom that Blender made, brought into warp-hair as a new user would: `examples/from_blender.py --render`.

    python benchmarks/make_blender_groom.py [--out benchmarks/out/blender_groom] [--spp 256] [--resolution 96]
                                            [--threads 2] [--no-render]   # bpy 4.5 (Python 3.11): builds, renders
    python benchmarks/make_blender_groom.py --compare 256 [--out ...]     # warp-hair at the truth vs Cycles
    warp-hair fit benchmarks/out/blender_groom -o FIT

Builds a Blender 4.5 scene from nothing with bpy and saves it as OUT/blender/groom.blend:
- the scalp: a cap of a sphere of radius 0.3 (30° from its centre, which leans 30° from the top toward the
  camera), a grid mesh pressed onto the sphere with its own UV map (a UV sphere's cap reaches the pole, whose
  degenerate UVs make Interpolate Hair Curves drop a different few strands in every process), hidden from
  renders: warp-hair renders fibers only;
- the groom: a hair Curves object on it holding 40 guides combed here (leaving along the scalp's normal, hanging
  down over 0.1 of arc length, 0.4 long ±10%, bent by `mathutils.noise`), and the hair modifiers of Blender's
  Essentials library (datafiles/assets/geometry_nodes/procedural_hair_node_assets.blend) as an artist stacks
  them: Attach Hair Curves to Surface (without Align to Surface Normal, which swung these guides in under the
  head), Interpolate Hair Curves (Poisson disk, about 600 strands), Clump Hair
  Curves, Curl Hair Curves (waves, each strand in its own phase), Hair Curves Noise, Set Hair Curve Profile
  (radius 0.001 at the root, 0.0006 at the tip). Blender evaluates them; nothing of warp-hair's generators;
- the look: a Principled Hair BSDF, Chiang model, Direct Coloring (`HAIR` below; every other input Blender's
  default: Coat 0, Random Roughness 0);
- the world: an Environment Texture of an HDRI file (OUT/blender/hdri.exr: benchmarks/synthetic_sky.py's map, a
  sun disc off every axis over coloured gradients, as a file Blender reads with +Z up) turned by a Mapping node
  (`ROTATION_Z`), Linear interpolation as Blender sets it; the sun stands up and to the left, in front;
- a perspective camera (135 mm lens on the 36 mm sensor) in front and to the right, looking 11° down: the
  horizon stays out of the frame, because Cycles' Linear interpolation blurs the map's sky-to-ground step over
  about two of its pixels where warp-hair looks up the nearest, so a horizon in view differs by up to 3× in a
  band of rows that no control of the look can explain. `--resolution` pixels square, Cycles limited to
  `--threads` threads (saved in the .blend; from_blender leaves it).
Then runs `examples/from_blender.py OUT/blender/groom.blend OUT --render SPP` in a new process, as a user would,
which writes the target (groom.usdc, sky.exr, scene.toml, image.exr, target.toml), and writes OUT/truth.json:
the look in warp-hair's controls. from_blender reads Direct Coloring's Color as `albedo`, which is what
`warp-hair export --to cycles` writes for an albedo look (warp_hair/export/cycles.py), Offset (radians) as
`alpha` in degrees, Coat 0 as `r_roughness_scale` 1.

`--compare SPP` (needs usd-core to read groom.usdc, not bpy) renders OUT/scene.toml in warp-hair at the truth with
two seeds and prints the channel means against Cycles' image.exr, over the image and over the pixels the hair
covers, and the 8×8-block RMSE beside the noise of the two seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from synthetic_sky import synthetic_sky

HERE = Path(__file__).resolve().parent
FROM_BLENDER = HERE.parent / "examples" / "from_blender.py"
# The Principled Hair BSDF's inputs (Direct Coloring) and the same look in warp-hair's controls.
COLOR = (0.42, 0.27, 0.16)
HAIR_INPUTS = {"Roughness": 0.3, "Radial Roughness": 0.4, "Offset": math.radians(2.0), "IOR": 1.55}
HAIR = {"albedo": list(COLOR), "beta_m": 0.3, "beta_n": 0.4, "alpha": 2.0, "eta": 1.55, "r_roughness_scale": 1.0}
HEAD_RADIUS = 0.3
CAP_CENTRE = (0.0, -0.5, 0.866)  # Blender's frame, Z up; the camera looks along +Y
CAP_ANGLE = 30.0
GUIDES, GUIDE_POINTS = 40, 24
LENGTH, LENGTH_JITTER, FALL = 0.4, 0.1, 0.1
DENSITY = 7000.0  # strands per unit area of the scalp: about 600 on its 0.0755
ROOT_RADIUS, TIP_RADIUS = 0.001, 0.0006
# Toward the sun in Blender's frame: up, to the camera's left, in front of the groom.
SUN = (-0.5, -0.6, 0.62)
ROTATION_Z = 45.0  # the Mapping node's turn, a whole number of the map's 256 columns (1.40625° each)
CAMERA = {"location": (0.5, -2.4, 0.55), "look_at": (0.0, -0.2, 0.1), "lens": 135.0}
ESSENTIALS = "datafiles/assets/geometry_nodes/procedural_hair_node_assets.blend"


def _scalp(bpy, bmesh, Vector):
    """The cap as a grid pressed radially onto the sphere: clean, non-overlapping UVs (see the docstring)."""
    centre = Vector(CAP_CENTRE).normalized()
    e1 = Vector((1.0, 0.0, 0.0))
    e2 = centre.cross(e1)
    reach = math.tan(math.radians(CAP_ANGLE) * 1.05)
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")
    bmesh.ops.create_grid(bm, x_segments=48, y_segments=48, size=1.0, calc_uvs=True)
    for v in bm.verts:
        v.co = HEAD_RADIUS * (centre + reach * (v.co.x * e1 + v.co.y * e2)).normalized()
    cos_max = math.cos(math.radians(CAP_ANGLE))
    outside = [f for f in bm.faces if f.calc_center_median().normalized().dot(centre) < cos_max]
    bmesh.ops.delete(bm, geom=outside, context="FACES")
    bmesh.ops.delete(bm, geom=[v for v in bm.verts if not v.link_faces], context="VERTS")
    mesh = bpy.data.meshes.new("scalp")
    bm.to_mesh(mesh)
    bm.free()
    mesh.shade_smooth()
    scalp = bpy.data.objects.new("scalp", mesh)
    scalp.hide_render = True  # warp-hair renders fibers only: the target must not see the head
    bpy.context.scene.collection.objects.link(scalp)
    return scalp


def _guides(Vector, noise):
    """Guide strands (GUIDES, GUIDE_POINTS, 3): roots on the cap, along the normal, turning to hang down over
    FALL, each bent by Blender's Perlin noise field (`mathutils.noise`, seeded)."""
    noise.seed_set(7)
    centre = Vector(CAP_CENTRE).normalized()
    roots = []
    while len(roots) < GUIDES:
        v = noise.random_unit_vector()
        if v.dot(centre) >= math.cos(math.radians(0.95 * CAP_ANGLE)):
            roots.append(v)
    down = Vector((0.0, 0.0, -1.0))
    strands = []
    for k, normal in enumerate(roots):
        step = LENGTH * (1.0 + LENGTH_JITTER * (2.0 * noise.random() - 1.0)) / (GUIDE_POINTS - 1)
        p = normal * HEAD_RADIUS
        points = [p.copy()]
        for i in range(1, GUIDE_POINTS):
            w = 1.0 - math.exp(-(i - 0.5) * step / FALL)
            d = ((1.0 - w) * normal + w * down).normalized()
            d = (d + 0.15 * w * noise.noise_vector(p * 8.0 + Vector((3.1 * k, 0.0, 0.0)))).normalized()
            p = p + d * step
            points.append(p.copy())
        strands.append([tuple(q) for q in points])
    return np.asarray(strands, dtype=np.float32)


def _hair_modifier(bpy, obj, name, **inputs):
    """A NODES modifier running the Essentials node group `name`, inputs by name (spaces as underscores)."""
    group = bpy.data.node_groups[name]
    modifier = obj.modifiers.new(name, "NODES")
    modifier.node_group = group
    # "Surface" names both a geometry and an object socket; a modifier takes the object.
    ids = {
        item.name.replace(" ", "_"): item.identifier
        for item in group.interface.items_tree
        if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.socket_type != "NodeSocketGeometry"
    }
    for key, value in inputs.items():
        modifier[ids[key]] = value
    return modifier


def _groom(bpy, scalp, material, Vector, noise):
    guides = _guides(Vector, noise)
    curves = bpy.data.hair_curves.new("groom")
    curves.add_curves([GUIDE_POINTS] * GUIDES)
    curves.position_data.foreach_set("vector", guides.ravel())
    curves.surface = scalp
    curves.surface_uv_map = "UVMap"
    curves.materials.append(material)
    obj = bpy.data.objects.new("groom", curves)
    bpy.context.scene.collection.objects.link(obj)
    path = Path(bpy.utils.resource_path("LOCAL")) / ESSENTIALS
    names = [
        "Attach Hair Curves to Surface",
        "Interpolate Hair Curves",
        "Clump Hair Curves",
        "Curl Hair Curves",
        "Hair Curves Noise",
        "Set Hair Curve Profile",
    ]
    with bpy.data.libraries.load(str(path)) as (_, data):
        data.node_groups = list(names)  # the loader swaps the list's names for the groups
    _hair_modifier(bpy, obj, names[0], Surface=scalp, Align_to_Surface_Normal=False)
    _hair_modifier(bpy, obj, names[1], Surface=scalp, Density=DENSITY, Interpolation_Guides=3, Seed=3)
    _hair_modifier(bpy, obj, names[2], Guide_Distance=0.05, Factor=0.9, Shape=0.5, Tip_Spread=0.003, Seed=5)
    _hair_modifier(bpy, obj, names[3], Radius=0.006, Frequency=3.0, Curl_Start=0.15, Random_Offset=1.0, Seed=11)
    _hair_modifier(bpy, obj, names[4], Distance=0.004, Scale=6.0, Seed=13)
    _hair_modifier(bpy, obj, names[5], Radius=ROOT_RADIUS, Factor_Min=TIP_RADIUS / ROOT_RADIUS, Factor_Max=1.0)
    return obj


def _material(bpy):
    material = bpy.data.materials.new("hair")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    nodes.clear()
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.model, hair.parametrization = "CHIANG", "COLOR"
    hair.inputs["Color"].default_value = (*COLOR, 1.0)
    for name, value in HAIR_INPUTS.items():
        hair.inputs[name].default_value = value
    output = nodes.new("ShaderNodeOutputMaterial")
    material.node_tree.links.new(hair.outputs["BSDF"], output.inputs["Surface"])
    return material


def hdri():
    """synthetic_sky's map for the sun at SUN, as the file Blender reads under the Mapping node's ROTATION_Z.

    synthetic_sky works in warp-hair's Y-up lat-long convention; Blender's frame exported Y up is (x, z, −y), and
    Cycles' u is warp-hair's + 1/4 − ROTATION_Z/360 (warp_hair.renderer.envmap.from_blender): the columns turn back.
    """
    sun = (SUN[0], SUN[2], -SUN[1])
    image = synthetic_sky(sun=sun)
    width = image.shape[1]
    return np.roll(image, -round(width * (ROTATION_Z / 360.0 - 0.25)) % width, axis=1)


def _world(bpy, path):
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    texture = nodes.new("ShaderNodeTexEnvironment")
    texture.image = bpy.data.images.load(str(path))
    coordinates = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value[2] = math.radians(ROTATION_Z)
    links.new(coordinates.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], texture.inputs["Vector"])
    links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
    nodes["Background"].inputs["Strength"].default_value = 1.0
    bpy.context.scene.world = world


def _camera(bpy, scene, resolution, Vector):
    data = bpy.data.cameras.new("camera")
    data.lens, data.sensor_fit = CAMERA["lens"], "AUTO"
    obj = bpy.data.objects.new("camera", data)
    obj.location = CAMERA["location"]
    forward = Vector(CAMERA["look_at"]) - Vector(CAMERA["location"])
    obj.rotation_euler = forward.to_track_quat("-Z", "Y").to_euler()  # a camera looks down −Z with +Y up
    scene.collection.objects.link(obj)
    scene.camera = obj
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100


def build(blend, resolution, threads):
    """Makes the scene of the module docstring and saves it as `blend` (its HDRI beside it)."""
    try:
        import bpy  # first: it makes Blender's bmesh and mathutils importable
    except ImportError as error:
        raise SystemExit(
            f'building the scene needs bpy 4.5 (Python 3.11, `pip install "bpy==4.5.*"`): {error}'
        ) from None
    import bmesh
    from mathutils import Vector, noise

    from warp_hair.io import write_exr

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    blend.parent.mkdir(parents=True, exist_ok=True)
    write_exr(blend.parent / "hdri.exr", hdri())
    _world(bpy, blend.parent / "hdri.exr")
    scalp = _scalp(bpy, bmesh, Vector)
    groom = _groom(bpy, scalp, _material(bpy), Vector, noise)
    _camera(bpy, scene, resolution, Vector)
    scene.render.engine = "CYCLES"
    scene.render.threads_mode, scene.render.threads = "FIXED", threads
    evaluated = groom.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return len(evaluated.curves), len(evaluated.points)


def bare_sky(scene, n=4):
    """The scene's image without the hair: each pixel the mean of n×n rays' map pixels (warp-hair's nearest-pixel
    lookup, warp_hair/renderer/envmap.py), to tell the pixels the hair covers from the sky's."""
    from warp_hair.renderer.camera import camera_rays

    width, height = scene.camera.resolution
    sky = scene.lights[0].image
    py, px = np.mgrid[0:height, 0:width]
    total = np.zeros((height, width, 3))
    for jitter in np.stack(np.meshgrid(*2 * [(np.arange(n) + 0.5) / n]), -1).reshape(-1, 2):
        _, d = camera_rays(scene.camera, px, py, jitter)
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        u = np.mod(np.arctan2(d[..., 0], -d[..., 2]) / (2.0 * np.pi), 1.0)
        v = np.arctan2(np.hypot(d[..., 0], d[..., 2]), d[..., 1]) / np.pi
        rows = np.clip((v * sky.shape[0]).astype(int), 0, sky.shape[0] - 1)
        columns = np.clip((u * sky.shape[1]).astype(int), 0, sky.shape[1] - 1)
        total += sky[rows, columns]
    return total / n**2


def compare(out, spp, threads):
    """warp-hair at the truth against Cycles' image.exr: channel means over the image and over the pixels the hair
    covers, 8×8-block RMSE, beside two warp-hair seeds' noise."""
    from vs_peers import block_rmse, fmt

    from warp_hair.io import read_exr, write_exr
    from warp_hair.renderer.render import render
    from warp_hair.scene import load_scene

    scene = load_scene(out / "scene.toml")
    truth = json.loads((out / "truth.json").read_text(encoding="utf-8"))
    for key, value in truth.items():
        if not np.allclose(getattr(scene.hair, key), value, rtol=1e-6):
            raise SystemExit(
                f"{out / 'scene.toml'}: [hair] {key} = {getattr(scene.hair, key)} is not the truth {value}"
            )
    cycles, _ = read_exr(out / "image.exr")
    images = []
    for seed in (0, 1):
        scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, spp=spp, seed=seed))
        start = time.perf_counter()
        images.append(render(scene, threads=threads))
        print(f"warp-hair, {spp} spp, seed {seed}: {time.perf_counter() - start:.0f} s")
    ours = images[0]
    write_exr(out.parent / f"{out.name}_warp_hair.exr", ours)
    sky = bare_sky(scene)
    hair = np.any(np.abs(0.5 * (images[0] + images[1]) - sky) > 0.02 * sky, axis=-1)
    bare = sky[~hair].mean(0)
    print(
        f"the hair covers {hair.mean():.0%} of the pixels; the others over the bare sky: Cycles "
        f"{fmt(cycles[~hair].mean(0) / bare)}, warp-hair {fmt(ours[~hair].mean(0) / bare)}"
    )
    for what, pick in (("image", np.ones_like(hair)), ("hair pixels", hair)):
        a, b, c = ours[pick].mean(0), cycles[pick].mean(0), images[1][pick].mean(0)
        print(f"{what}: warp-hair / Cycles means {fmt(a)} / {fmt(b)} = {fmt(a / b)} (seed 1 / seed 0 {fmt(c / a)})")
    print(f"block RMSE {block_rmse(ours, cycles):.2%} (two warp-hair seeds: {block_rmse(images[1], ours):.2%})")


def _positive(text):
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number ≥ 1, got {text}")
    return value


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE / "out" / "blender_groom")
    parser.add_argument("--resolution", type=_positive, default=96)
    parser.add_argument("--spp", type=_positive, default=256, help="Cycles' samples per pixel (from_blender --render)")
    parser.add_argument("--threads", type=_positive, default=2, help="Cycles' threads, saved in the .blend")
    parser.add_argument("--no-render", action="store_true", help="convert only: no Cycles render, no image.exr")
    parser.add_argument(
        "--compare", type=_positive, metavar="SPP", help="render the made target in warp-hair at the truth and compare"
    )
    args = parser.parse_args(argv)
    out = args.out.resolve()
    if args.compare:
        return compare(out, args.compare, args.threads)
    start = time.perf_counter()
    blend = out / "blender" / "groom.blend"
    strands, points = build(blend, args.resolution, args.threads)
    print(f"{blend}: {strands} strands, {points} points, {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    command = [sys.executable, str(FROM_BLENDER), str(blend), str(out)]
    command += [] if args.no_render else ["--render", str(args.spp)]
    print("$", " ".join(command), flush=True)
    subprocess.run(command, check=True)
    (out / "truth.json").write_text(json.dumps(HAIR, indent=2) + "\n", encoding="utf-8")
    print(f"from_blender: {time.perf_counter() - start:.0f} s; wrote {out / 'truth.json'}")


if __name__ == "__main__":
    main()
