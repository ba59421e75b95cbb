"""Bring a groom, its camera and its HDRI from a Blender scene into a warp-hair target directory.

    python examples/from_blender.py scene.blend OUT [--hair OBJECT ...] [--render SPP]      # bpy module (4.5)
    blender -b scene.blend --python examples/from_blender.py -- OUT [--hair OBJECT ...]     # Blender itself

Writes to OUT:
- `groom.usdc`: the hair objects (default: every Curves object) through Blender's own USD exporter, turned
  Y up (`convert_orientation`, forward −Z, up Y: Blender's (x, y, z) becomes (x, z, −y));
- `sky.exr`: the world's Environment Texture re-indexed into warp-hair's lat-long convention for that frame
  (`warp_hair.renderer.envmap.from_blender`, which takes a Mapping node's Z rotation); the Background
  strength becomes the light's `scale`;
- `scene.toml`: [camera] from the scene's camera in the same frame (perspective: the horizontal field of view
  as Blender's sensor fit gives it; orthographic: the width), the resolution as Blender renders it; [hair]
  from the hair's Principled Hair BSDF (Chiang, Direct Coloring: Color, Roughness, Radial Roughness, Offset,
  IOR) or warp-hair's defaults; [render] `interpenetration = "exit"`, as Cycles 4.x renders grooms whose
  strands pass through each other on the CPU;
- with `--render SPP`: `image.exr`, the scene rendered by Cycles at SPP samples with the settings under which
  its estimate is the one warp-hair computes (no denoising, clamping, glossy filter or adaptive sampling, a box
  pixel filter, every bounce kind up to max_depth − 1, linear EXR), and `target.toml`: then
  `warp-hair fit OUT -o FIT` fits the look to it. Without it, put your own render of the same camera as
  OUT/image.exr and write target.toml as `warp-hair targets` documents.
Errors name what the script could not translate (a Mapping node that turns about X or Y, a world without an
Environment Texture, a camera that is neither perspective nor orthographic).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

# Blender's (x, y, z) → warp-hair's Y-up frame, as Blender's USD export with convert_orientation writes it.
# The Principled Hair BSDF's inputs that are warp-hair's controls (warp_hair/export/cycles.py has the mapping).
CHIANG_INPUTS = ("Color", "Roughness", "Radial Roughness", "Offset", "IOR")
TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _fmt(values):
    return "[" + ", ".join(f"{float(v):.9g}" for v in values) + "]"


def camera_table(scene):
    """The [camera] table of the scene's camera, in the Y-up frame."""
    obj = scene.camera
    if obj is None:
        raise SystemExit("the scene has no camera (set Scene > Camera)")
    matrix = np.array(obj.matrix_world)
    origin = TO_Y_UP @ matrix[:3, 3]
    forward = TO_Y_UP @ -matrix[:3, 2]  # Blender cameras look down their local −Z, +Y up
    up = TO_Y_UP @ matrix[:3, 1]
    render = scene.render
    width = round(render.resolution_x * render.resolution_percentage / 100)
    height = round(render.resolution_y * render.resolution_percentage / 100)
    if render.pixel_aspect_x != render.pixel_aspect_y:
        raise SystemExit("warp-hair renders square pixels; set the pixel aspect to 1:1")
    aspect = width / height
    data = obj.data
    # Which image side the sensor (or ortho_scale) spans: AUTO takes the larger one.
    horizontal = data.sensor_fit == "HORIZONTAL" or (data.sensor_fit == "AUTO" and aspect >= 1.0)
    lines = [
        "[camera]",
        f"origin = {_fmt(origin)}",
        f"target = {_fmt(origin + forward)}",
        f"up = {_fmt(up)}",
        f"resolution = [{width}, {height}]",
    ]
    if data.type == "PERSP":
        sensor = data.sensor_height if data.sensor_fit == "VERTICAL" else data.sensor_width
        half = math.atan(sensor / (2.0 * data.lens))
        if not horizontal:  # the sensor spans the height: the horizontal half-angle follows from the aspect
            half = math.atan(math.tan(half) * aspect)
        lines[1:1] = ['type = "perspective"']
        lines.append(f"fov = {math.degrees(2.0 * half):.9g}")
    elif data.type == "ORTHO":
        lines[1:1] = ['type = "orthographic"']
        lines.append(f"width = {data.ortho_scale if horizontal else data.ortho_scale * aspect:.9g}")
    else:
        raise SystemExit(f"camera {obj.name!r} is {data.type}; warp-hair has perspective and orthographic cameras")
    if data.shift_x or data.shift_y:
        raise SystemExit(f"camera {obj.name!r} has a lens shift, which warp-hair's camera does not have")
    return "\n".join(lines)


def environment(world, out):
    """Writes OUT/sky.exr from the world's Environment Texture; returns the [[lights]] table."""
    from warp_hair.io import write_exr
    from warp_hair.renderer.envmap import from_blender

    tree = world.node_tree if world is not None and world.use_nodes else None
    background = next((n for n in tree.nodes if n.type == "BACKGROUND"), None) if tree else None
    link = background.inputs["Color"].links[0] if background and background.inputs["Color"].is_linked else None
    texture = link.from_node if link else None
    if texture is None or texture.type != "TEX_ENVIRONMENT" or texture.image is None:
        raise SystemExit("the world's Background colour must come from an Environment Texture with an image")
    if texture.projection != "EQUIRECTANGULAR":
        raise SystemExit(f"the Environment Texture is {texture.projection}; warp-hair reads lat-long maps")
    rotation_z = 0.0
    if texture.inputs["Vector"].is_linked:
        mapping = texture.inputs["Vector"].links[0].from_node
        if mapping.type != "MAPPING" or mapping.vector_type not in ("POINT", "VECTOR"):
            raise SystemExit("only a Mapping node (Point or Vector) may feed the Environment Texture's vector")
        rotation = mapping.inputs["Rotation"].default_value
        scale = mapping.inputs["Scale"].default_value
        moved = mapping.vector_type == "POINT" and any(abs(v) > 1e-6 for v in mapping.inputs["Location"].default_value)
        if abs(rotation[0]) > 1e-6 or abs(rotation[1]) > 1e-6 or any(abs(s - 1.0) > 1e-6 for s in scale) or moved:
            raise SystemExit("the Mapping node may only turn the map about Z (rotation X, Y = 0, scale 1, no location)")
        rotation_z = math.degrees(rotation[2])
    image = texture.image
    width, height = image.size
    pixels = np.empty(width * height * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)  # scene-linear RGBA, bottom row first
    rgb = pixels.reshape(height, width, 4)[::-1, :, :3]
    write_exr(out / "sky.exr", from_blender(rgb, rotation_z))
    strength = background.inputs["Strength"].default_value
    return f'[[lights]]\ntype = "environment"\nfile = "sky.exr"\nscale = {strength:.9g}'


def hair_table(objects):
    """[hair] from the first Principled Hair BSDF (Chiang, Direct Coloring) on the hair objects."""
    for obj in objects:
        for material in obj.data.materials:
            for node in material.node_tree.nodes if material and material.use_nodes else ():
                if node.type == "BSDF_HAIR_PRINCIPLED" and node.model == "CHIANG" and node.parametrization == "COLOR":
                    inputs = {name: node.inputs[name].default_value for name in CHIANG_INPUTS}
                    return "\n".join(
                        [
                            "[hair]",
                            f"albedo = {_fmt(inputs['Color'][:3])}",
                            f"beta_m = {inputs['Roughness']:.9g}",
                            f"beta_n = {inputs['Radial Roughness']:.9g}",
                            f"alpha = {math.degrees(inputs['Offset']):.9g}",
                            f"eta = {inputs['IOR']:.9g}",
                        ]
                    )
    print("no Principled Hair BSDF (Chiang, Direct Coloring) on the hair: [hair] holds warp-hair's defaults")
    return "[hair]\nalbedo = [0.5, 0.5, 0.5]"


def unbiased_settings(scene, spp, max_depth):
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.samples, c.use_adaptive_sampling, c.use_denoising = spp, False, False
    c.blur_glossy = c.sample_clamp_direct = c.sample_clamp_indirect = c.light_sampling_threshold = 0.0
    c.caustics_reflective = c.caustics_refractive = True
    c.max_bounces = max_depth - 1
    for kind in ("diffuse", "glossy", "transmission", "volume", "transparent_max"):
        setattr(c, f"{kind}_bounces", max_depth - 1)
    c.pixel_filter_type, c.filter_width = "BOX", 1.0
    scene.cycles_curves.shape = "THICK"
    scene.render.film_transparent = False
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth, settings.color_mode = "OPEN_EXR", "32", "RGB"


def main(argv=None):
    import bpy

    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    if not bpy.data.filepath:
        parser.add_argument("blend", type=Path, help="the .blend file (when run with the bpy module)")
    parser.add_argument("out", type=Path)
    parser.add_argument("--hair", nargs="*", help="the hair objects (default: every Curves object)")
    parser.add_argument("--render", type=int, metavar="SPP", help="render image.exr with Cycles at SPP samples")
    parser.add_argument("--max-depth", type=int, default=64, help="the longest path, in scattering vertices")
    args = parser.parse_args(argv)
    if not bpy.data.filepath:
        bpy.ops.wm.open_mainfile(filepath=str(args.blend))
    scene = bpy.context.scene
    hair = [o for o in scene.objects if (o.name in args.hair if args.hair else o.type == "CURVES")]
    if not hair:
        raise SystemExit("no hair: name the objects with --hair, or the scene needs a Curves object")
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in hair:
        obj.select_set(True)
    bpy.ops.wm.usd_export(
        filepath=str(out / "groom.usdc"),
        selected_objects_only=True,
        export_materials=False,
        convert_orientation=True,
        export_global_forward_selection="NEGATIVE_Z",
        export_global_up_selection="Y",
    )
    tables = [
        camera_table(scene),
        environment(scene.world, out),
        '[fibers]\nfile = "groom.usdc"',
        hair_table(hair),
        "\n".join(
            ["[render]"]
            # The target's samples: its noise, which the fit's σ, step count and measure of fit are taken from.
            + ([f"spp = {args.render}"] if args.render else [])
            + [f"max_depth = {args.max_depth}", 'interpenetration = "exit"']
        ),
    ]
    (out / "scene.toml").write_text(
        f"# From {bpy.data.filepath} by examples/from_blender.py.\n" + "\n\n".join(tables) + "\n", encoding="utf-8"
    )
    print(f"wrote {out / 'groom.usdc'}, {out / 'sky.exr'}, {out / 'scene.toml'}")
    if args.render:
        unbiased_settings(scene, args.render, args.max_depth)
        scene.render.filepath = str(out / "image.exr")
        bpy.ops.render.render(write_still=True)
        (out / "target.toml").write_text(
            'renderer = "cycles"\n\n[[images]]\nscene = "scene.toml"\nimage = "image.exr"\n', encoding="utf-8"
        )
        print(f"wrote {out / 'image.exr'}, {out / 'target.toml'}: warp-hair fit {out} -o FIT")


if __name__ == "__main__":
    main()
