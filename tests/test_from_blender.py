"""examples/from_blender.py: a Blender scene's groom, camera and HDRI brought into warp-hair's frame (opt-in, bpy)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warp_hair.geometry import load_fibers, save_fibers
from warp_hair.geometry.generators import wavy
from warp_hair.io import read_exr, write_exr
from warp_hair.scene import load_scene

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "from_blender.py"

# A Blender scene made from a warp-hair one as a Blender user would have it: the groom imported by Blender's USD
# importer (Y up turned Z up), the camera placed in Blender's frame (x, −z, y), the map turned by a Mapping node.
BUILD = """
import math, sys
import bpy, numpy as np
from mathutils import Matrix, Vector
usd, hdri, blend, rotation = sys.argv[1:5]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
bpy.ops.wm.usd_import(filepath=usd, apply_unit_conversion_scale=False)  # a groom authored in metres
to_blender = lambda v: Vector((v[0], -v[2], v[1]))
origin, target, up = to_blender((0.1, 0.2, 2.0)), to_blender((0.0, 0.05, 0.0)), to_blender((0.0, 1.0, 0.0))
camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
z = (origin - target).normalized(); x = up.cross(z).normalized()
camera.matrix_world = Matrix.Translation(origin) @ Matrix((x, z.cross(x), z)).transposed().to_4x4()
camera.data.lens, camera.data.sensor_fit = 80.0, "AUTO"
scene.collection.objects.link(camera); scene.camera = camera
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 60, 40, 100
world = bpy.data.worlds.new("world"); world.use_nodes = True; scene.world = world
nodes, links = world.node_tree.nodes, world.node_tree.links
texture = nodes.new("ShaderNodeTexEnvironment"); texture.image = bpy.data.images.load(hdri)
mapping = nodes.new("ShaderNodeMapping"); mapping.inputs["Rotation"].default_value[2] = math.radians(float(rotation))
coordinates = nodes.new("ShaderNodeTexCoord")
links.new(coordinates.outputs["Generated"], mapping.inputs["Vector"])
links.new(mapping.outputs["Vector"], texture.inputs["Vector"])
links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
nodes["Background"].inputs["Strength"].default_value = 2.0
material = bpy.data.materials.new("hair"); material.use_nodes = True
hair = material.node_tree.nodes.new("ShaderNodeBsdfHairPrincipled")
hair.model, hair.parametrization = "CHIANG", "COLOR"
hair.inputs["Color"].default_value = (0.4, 0.3, 0.2, 1.0)
for name, value in (("Roughness", 0.27), ("Radial Roughness", 0.35), ("Offset", math.radians(2.0)), ("IOR", 1.5)):
    hair.inputs[name].default_value = value
next(o for o in scene.objects if o.type == "CURVES").data.materials.append(material)
bpy.ops.wm.save_as_mainfile(filepath=blend)
"""


@pytest.mark.bpy
def test_from_blender_brings_groom_camera_and_map_back_to_warp_hair_frame(tmp_path):
    pytest.importorskip("bpy", reason="bpy 4.5 (Python 3.11) is the `blender` extra")
    fibers = wavy(count=12, layers=2, length=0.3, segments=8, seed=1)
    save_fibers(fibers, tmp_path / "groom.usda")
    # The map in warp-hair's convention, and the file a Blender user would hold for it under a 45° Mapping.
    sky = np.random.default_rng(0).uniform(0.1, 1.0, (16, 32, 3)).astype(np.float32)
    write_exr(tmp_path / "blender_sky.exr", np.roll(sky, -round(32 * (45.0 / 360.0 - 0.25)) % 32, axis=1))
    blend = tmp_path / "scene.blend"
    run = [sys.executable, "-c", BUILD, str(tmp_path / "groom.usda"), str(tmp_path / "blender_sky.exr"), str(blend)]
    subprocess.run([*run, "45"], capture_output=True, text=True, timeout=300, check=True)
    out = tmp_path / "target"
    subprocess.run(
        [sys.executable, str(EXAMPLE), str(blend), str(out)], capture_output=True, text=True, timeout=300, check=True
    )
    scene = load_scene(out / "scene.toml")
    np.testing.assert_allclose(scene.camera.origin, (0.1, 0.2, 2.0), atol=1e-5)
    direction = np.subtract(scene.camera.target, scene.camera.origin)
    expected = np.subtract((0.0, 0.05, 0.0), (0.1, 0.2, 2.0))
    np.testing.assert_allclose(direction / np.linalg.norm(direction), expected / np.linalg.norm(expected), atol=1e-6)
    assert abs(np.dot(scene.camera.up, direction)) < 1e-6 and scene.camera.up[1] > 0.99
    # 80 mm on Blender's 36 mm sensor spans the wider side, here the width.
    assert scene.camera.resolution == (60, 40)
    assert scene.camera.fov == pytest.approx(np.degrees(2 * np.arctan(18.0 / 80.0)), abs=1e-6)
    image, _ = read_exr(out / "sky.exr")
    np.testing.assert_array_equal(image, sky)
    assert scene.lights[0].scale == 2.0
    assert scene.render.interpenetration == "exit"
    np.testing.assert_allclose(scene.hair.albedo, (0.4, 0.3, 0.2), rtol=1e-6)
    assert (scene.hair.beta_m, scene.hair.beta_n, scene.hair.eta) == pytest.approx((0.27, 0.35, 1.5), rel=1e-6)
    assert scene.hair.alpha == pytest.approx(2.0, rel=1e-6)
    groom = load_fibers(out / "groom.usdc")
    np.testing.assert_allclose(groom.points, fibers.points, atol=1e-6)
    np.testing.assert_allclose(groom.radii, fibers.radii, rtol=1e-6)
