"""Blender Cycles as a reference renderer: a warp-hair scene rendered by `bpy` (Blender as a Python module).

    from cycles_peer import import_bpy, render_cycles
    image = render_cycles(bpy, scene, spp=256, threads=2)    # float32 (H, W, 3) linear radiance, row 0 on top

`pip install "bpy==4.5.*"` (about 370 MB; Blender 4.5 LTS, Python 3.11) renders headless with no system
packages. What the translation sets, and why (each one measured to matter, or Cycles' documented behaviour):
- Strands become a hair `Curves` object (Catmull-Rom through the vertices, radius per vertex) drawn as THICK
  curves: round tubes, as ours.
  Where strands pass through each other, Cycles on the CPU (Embree 4) scatters where a ray leaves another
  strand's tube: warp-hair's `[render] interpenetration = "exit"` (docs/scenes.md, "Interpenetrating strands").
- The material is the look as `warp-hair export --to cycles` writes it (`warp_hair.export.cycles` documents
  the conversion), so this also checks the export; or, given `node`, a Principled Hair BSDF with those inputs set
  directly (Cycles' own melanin, Random Color and Random Roughness, which the exporter does not write), its
  Random input unlinked: each curve then draws Cycles' per-curve random value. `melanin_controls` says what
  warp-hair's controls such a node is.
- An unbiased estimator: filter glossy 0, no clamping, light threshold 0, no denoising, no adaptive sampling,
  caustics kept, every bounce kind allowed up to the scene's max_depth. Cycles counts the bounces after the
  first hit (0 is direct lighting only), ours the scattering vertices (1 is direct lighting): ours − 1.
- Film: a box pixel filter of width 1, the Standard view transform (the EXR holds scene-linear radiance).
- Lights: a sun's strength is the irradiance on a surface facing it; the world colour × strength is the sky's
  radiance. Orthographic and perspective cameras. The backing card as a large diffuse square.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from warp_hair.export import export
from warp_hair.io import read_exr
from warp_hair.model.variation import CYCLES_MELANIN_UNITS, MELANIN_CLAMP
from warp_hair.scene import DirectionalLight, EnvironmentLight

# The Principled Hair inputs a `node` (render_cycles) may set in the melanin parametrisation, and what they are
# when not given (Blender 4.5's defaults, but for the randomisations, which default to 0 here).
MELANIN_INPUTS = {
    "Melanin": None,
    "Melanin Redness": None,
    "Tint": [1.0, 1.0, 1.0, 1.0],
    "Random Color": 0.0,
    "Random Roughness": 0.0,
    "Roughness": None,
    "Radial Roughness": None,
    "Coat": 0.0,
    "IOR": None,
    "Offset": None,
}


def import_bpy():
    """The bpy module, or None (with the reason printed)."""
    try:
        import bpy
    except ImportError as error:
        print(f'Cycles comparison skipped: {error}. Enable it with `pip install "bpy==4.5.*"`.')
        return None
    return bpy


def _reset(bpy):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _look_at(bpy, obj, origin, target, up):
    """Place obj at origin looking at target with `up` up: Blender cameras and suns look down their local −Z
    with +Y up, so the rotation's columns are (x, y, z) = (up × z, z × x, −forward)."""
    from mathutils import Matrix, Vector

    z = -(Vector(target) - Vector(origin)).normalized()
    x = Vector(up).cross(z).normalized()
    obj.location = Vector(origin)
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = Matrix((x, z.cross(x), z)).transposed().to_quaternion()


def _fibers(bpy, fibers, material):
    counts = [int(c) for c in fibers.vertex_counts]
    curves = bpy.data.hair_curves.new("fibers")
    curves.add_curves(counts)
    curves.position_data.foreach_set("vector", np.asarray(fibers.points, dtype=np.float32).ravel())
    radius = curves.attributes.get("radius") or curves.attributes.new("radius", "FLOAT", "POINT")
    radius.data.foreach_set("value", np.asarray(fibers.radii, dtype=np.float32))
    curves.materials.append(material)
    obj = bpy.data.objects.new("fibers", curves)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _material(bpy, hair, workdir):
    """The look's material exactly as `warp-hair export --to cycles` writes it: the exported script, run."""
    import runpy

    script = Path(workdir) / "hair_cycles.py"
    export(hair, "cycles", script)
    return runpy.run_path(str(script))["make_material"]()


def _node_material(bpy, node):
    """A Principled Hair BSDF (Chiang) with `node`'s parametrization and inputs, its Random input left unlinked."""
    material = bpy.data.materials.new("cycles hair")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    nodes.clear()
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.model = "CHIANG"
    hair.parametrization = node["parametrization"]
    for socket, value in node["inputs"].items():
        hair.inputs[socket].default_value = value
    output = nodes.new("ShaderNodeOutputMaterial")
    output.target = "CYCLES"
    material.node_tree.links.new(hair.outputs["BSDF"], output.inputs["Surface"])
    return material


def melanin_controls(node) -> dict:
    """warp-hair's controls (`HairParams.from_dict`) of a MELANIN-parametrised Principled Hair `node`
    ({"parametrization": "MELANIN", "inputs": {socket: value}}, MELANIN_INPUTS), as Cycles 4.5 renders it
    (svm/closure.h, the Principled Hair case): its concentration is M = −ln(1 − Melanin), eumelanin M(1 − Redness)
    and pheomelanin M·Redness in Cycles' coefficients, which are CYCLES_MELANIN_UNITS times d'Eon's (ours, to
    0.1%); Random Color and Random Roughness are color_spread and roughness_spread; Offset is α in radians.
    A ValueError for inputs no control of ours expresses (a tint, a coat)."""
    if node.get("parametrization") != "MELANIN":
        raise ValueError(f"parametrization {node.get('parametrization')!r}: only MELANIN is mapped")
    unknown = sorted(set(node["inputs"]) - set(MELANIN_INPUTS))
    if unknown:
        raise ValueError(f"input(s) {unknown} are not mapped; the node may set {list(MELANIN_INPUTS)}")
    missing = sorted(k for k, v in MELANIN_INPUTS.items() if v is None and k not in node["inputs"])
    if missing:
        raise ValueError(f"input(s) {missing} must be given")
    inputs = {**MELANIN_INPUTS, **node["inputs"]}
    if [float(c) for c in inputs["Tint"][:3]] != [1.0, 1.0, 1.0] or float(inputs["Coat"]) != 0.0:
        raise ValueError(f"Tint {inputs['Tint']} and Coat {inputs['Coat']}: only white and 0 are mapped")
    total = -math.log(max(1.0 - float(inputs["Melanin"]), MELANIN_CLAMP))
    redness = float(inputs["Melanin Redness"])
    return {
        "eumelanin": total * (1.0 - redness) * CYCLES_MELANIN_UNITS[0],
        "pheomelanin": total * redness * CYCLES_MELANIN_UNITS[1],
        "beta_m": float(inputs["Roughness"]),
        "beta_n": float(inputs["Radial Roughness"]),
        "alpha": math.degrees(float(inputs["Offset"])),
        "eta": float(inputs["IOR"]),
        "color_spread": float(inputs["Random Color"]),
        "roughness_spread": float(inputs["Random Roughness"]),
    }


def _lights(bpy, scene, lights, workdir):
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    background.inputs["Strength"].default_value = 1.0
    scene.world = world
    for k, light in enumerate(lights):
        if isinstance(light, DirectionalLight):
            sun = bpy.data.lights.new(f"sun{k}", type="SUN")
            # One strength and a colour: the irradiance's largest channel times the colour's ratios.
            strength = max(light.irradiance)
            sun.energy = float(strength)
            sun.color = tuple(float(c) / strength for c in light.irradiance)
            sun.angle = 0.0
            obj = bpy.data.objects.new(f"sun{k}", sun)
            direction = np.asarray(light.direction, dtype=np.float64)
            # A sun shines along its local −Z.
            _look_at(bpy, obj, (0.0, 0.0, 0.0), tuple(direction), _any_perpendicular(direction))
            scene.collection.objects.link(obj)
        elif isinstance(light, EnvironmentLight) and light.image is None:
            background.inputs["Color"].default_value = (*[float(c) for c in light.radiance], 1.0)
        else:
            _environment_map(bpy, world, light.image, workdir)


def _environment_map(bpy, world, image, workdir):
    """A lat-long map (warp_hair/renderer/envmap.py: +y up, u = 0 looking down −z, u = 1/4 along +x, row 0 at
    the top) as an Environment Texture that Cycles reads at the same pixel for every direction.

    Cycles (`kernel/geom/...`, `direction_to_equirectangular`, range (−2π, π, −π, π)) takes u = (π − atan2(y, x))
    / 2π and v = 1 − acos(z) / π of the lookup vector, with v = 0 the image's bottom row: +z up, u = 1/2 along
    +x, u = 1/4 along +y. Handing it (d.z, d.x, d.y) for the scene's direction d, a rotation, makes its u and v
    ours: −z → u 0, +x → 1/4, +z → 1/2, and the top row at +y. Closest interpolation is our nearest-pixel lookup.
    The image already carries the light's scale (EnvironmentLight.image), so the strength is 1.
    """
    from warp_hair.io import write_exr

    path = Path(workdir) / "environment.exr"
    write_exr(path, image)
    texture = world.node_tree.nodes.new("ShaderNodeTexEnvironment")
    texture.image = bpy.data.images.load(str(path))
    texture.image.colorspace_settings.name = "Non-Color"  # the radiance as stored, no colour transform
    texture.interpolation = "Closest"
    texture.projection = "EQUIRECTANGULAR"
    nodes, links = world.node_tree.nodes, world.node_tree.links
    coordinates = nodes.new("ShaderNodeTexCoord")  # a world's Generated coordinate is the ray's direction
    split = nodes.new("ShaderNodeSeparateXYZ")
    join = nodes.new("ShaderNodeCombineXYZ")
    links.new(coordinates.outputs["Generated"], split.inputs["Vector"])
    for theirs, ours in zip("XYZ", "ZXY"):
        links.new(split.outputs[ours], join.inputs[theirs])
    links.new(join.outputs["Vector"], texture.inputs["Vector"])
    links.new(texture.outputs["Color"], world.node_tree.nodes["Background"].inputs["Color"])


def _card(bpy, scene, fibers):
    """The backing card (warp_hair.geometry.card: a plane facing the camera behind the fibers, Lambertian on both
    sides) as a square mesh 10⁴ units across with a Diffuse BSDF of the card's albedo."""
    from warp_hair.geometry.card import card_plane

    points = np.asarray(fibers.points, dtype=np.float64)
    point, normal = card_plane(scene.card, scene.camera, (points.min(axis=0), points.max(axis=0)))
    u = np.asarray(_any_perpendicular(normal), dtype=np.float64)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    half = 5e3
    corners = [tuple(point + half * (a * u + b * v)) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    mesh = bpy.data.meshes.new("card")
    mesh.from_pydata(corners, [], [(0, 1, 2, 3)])
    material = bpy.data.materials.new("card")
    material.use_nodes = True
    bsdf = material.node_tree.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*[float(c) for c in scene.card.albedo], 1.0)
    output = material.node_tree.nodes.get("Material Output") or material.node_tree.nodes.new("ShaderNodeOutputMaterial")
    material.node_tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    mesh.materials.append(material)
    obj = bpy.data.objects.new("card", mesh)
    bpy.context.scene.collection.objects.link(obj)


def _any_perpendicular(d):
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 * np.linalg.norm(d) else np.array([1.0, 0.0, 0.0])
    return tuple(np.cross(np.cross(d, helper), d))


def _camera(bpy, scene, camera):
    data = bpy.data.cameras.new("camera")
    width, height = camera.resolution
    if camera.type == "orthographic":
        data.type = "ORTHO"
        # Blender's ortho_scale spans the larger image side.
        data.ortho_scale = camera.width * max(1.0, height / width)
    else:
        data.type = "PERSP"
        data.sensor_fit = "HORIZONTAL"
        data.angle = math.radians(camera.fov)
    data.clip_start, data.clip_end = 1e-4, 1e4
    obj = bpy.data.objects.new("camera", data)
    _look_at(bpy, obj, camera.origin, camera.target, camera.up)
    scene.collection.objects.link(obj)
    scene.camera = obj
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100


def _settings(scene, spp, max_depth, seed, threads):
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = spp
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = seed
    c.blur_glossy = 0.0  # "Filter Glossy"
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.light_sampling_threshold = 0.0
    c.caustics_reflective = True
    c.caustics_refractive = True
    c.max_bounces = max_depth - 1
    for kind in ("diffuse", "glossy", "transmission", "volume", "transparent_max"):
        setattr(c, f"{kind}_bounces", max_depth - 1)
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    scene.cycles_curves.shape = "THICK"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.film_transparent = False
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    settings.color_mode = "RGB"
    settings.exr_codec = "ZIP"


def _usd_fibers(bpy, path, material):
    """The BasisCurves of a USD file as Blender's own USD importer reads them (a Curves object per prim, radius
    = width / 2, the control points as they are, which Cycles draws as Catmull-Rom curves), left in the file's
    coordinates: the importer turns a Y-up stage to Blender's Z up and scales by metersPerUnit on the object,
    which is set back to the identity here, because the camera and the map are placed in the file's frame."""
    from mathutils import Matrix

    before = set(bpy.data.objects)
    result = bpy.ops.wm.usd_import(filepath=str(path))
    imported = [obj for obj in bpy.data.objects if obj not in before and obj.type == "CURVES"]
    if result != {"FINISHED"} or not imported:
        raise RuntimeError(f"{path}: Blender's USD importer found no curves ({result})")
    for obj in bpy.data.objects:
        if obj in before:
            continue
        obj.parent = None
        obj.matrix_world = Matrix.Identity(4)
        if obj.type == "CURVES":
            obj.data.materials.clear()
            obj.data.materials.append(material)
    return imported


def render_cycles(bpy, scene, spp, threads=None, seed=0, fibers=None, usd=None, material=None, node=None, props=None):
    """The warp-hair `scene` (its fibers, or `fibers`, or the curves of the USD file `usd` as Blender imports
    them) rendered by Cycles: float32 (H, W, 3), row 0 on top. In place of the scene's look as exported:
    `node`, Cycles' own Principled Hair inputs ({"parametrization": ..., "inputs": {socket: value}}), or
    `material(bpy)`, a material of the caller's (a probe of what Cycles' shader nodes see). `props(bpy)` adds
    objects the scene does not hold (a grey card in the shot)."""
    fibers = scene.fibers if fibers is None else fibers
    blender = _reset(bpy)
    _settings(blender, spp, scene.render.max_depth, seed, threads)
    _camera(bpy, blender, scene.camera)
    with tempfile.TemporaryDirectory() as tmp:
        _lights(bpy, blender, scene.lights, tmp)
        if material is not None:
            hair = material(bpy)
        elif node is not None:
            hair = _node_material(bpy, node)
        else:
            hair = _material(bpy, scene.hair, tmp)
        if usd is None:
            _fibers(bpy, fibers, hair)
        else:
            _usd_fibers(bpy, usd, hair)
        if scene.card is not None:
            _card(bpy, scene, fibers)
        if props is not None:
            props(bpy)
        path = Path(tmp) / "cycles.exr"
        blender.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        image, _ = read_exr(path)
    return image.astype(np.float32)
