"""Tests of warp_hair.scene: the TOML scene loader, its dict twin, and its error messages."""

import copy
import json
import re
from pathlib import Path

import numpy as np
import pytest

from warp_hair.geometry.formats import save_fibers
from warp_hair.geometry.generators import swatch
from warp_hair.io import write_exr
from warp_hair.scene import (
    Camera,
    Card,
    DirectionalLight,
    EnvironmentLight,
    RenderSettings,
    load_scene,
    scene_from_dict,
)

BENCHMARK = Path(__file__).parents[1] / "benchmarks" / "standard_swatch.toml"

SCENE_TOML = """
[camera]
type = "perspective"
origin = [0.0, 0.5, 4.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 30.0
resolution = [64, 48]

[[lights]]
type = "directional"
direction = [0.0, 0.0, -2.0]
irradiance = [1.0, 2.0, 3.0]

[[lights]]
type = "environment"
file = "sky.exr"
scale = 2.0

[fibers]
generator = "wavy"
count = 12
layers = 2
amplitude = 0.03

[hair]
albedo = [0.6, 0.4, 0.2]
beta_m = 0.25

[render]
spp = 4
seed = 7

[card]
albedo = [0.5, 0.5, 0.5]
"""

SCENE_DICT = {
    "camera": {
        "type": "perspective",
        "origin": [0.0, 0.5, 4.0],
        "target": [0.0, 0.0, 0.0],
        "up": [0.0, 1.0, 0.0],
        "fov": 30.0,
        "resolution": [64, 48],
    },
    "lights": [
        {"type": "directional", "direction": [0.0, 0.0, -2.0], "irradiance": [1.0, 2.0, 3.0]},
        {"type": "environment", "file": "sky.exr", "scale": 2.0},
    ],
    "fibers": {"generator": "wavy", "count": 12, "layers": 2, "amplitude": 0.03},
    "hair": {"albedo": [0.6, 0.4, 0.2], "beta_m": 0.25},
    "render": {"spp": 4, "seed": 7},
    "card": {"albedo": [0.5, 0.5, 0.5]},
}

SKY = np.linspace(0.0, 1.0, 4 * 8 * 3, dtype=np.float32).reshape(4, 8, 3)


@pytest.fixture
def scene_dir(tmp_path):
    """A folder holding scene.toml (SCENE_TOML), its sky.exr and a small fibers.txt."""
    write_exr(tmp_path / "sky.exr", SKY)
    save_fibers(swatch(count=6, layers=2, segments=2), tmp_path / "fibers.txt")
    (tmp_path / "scene.toml").write_text(SCENE_TOML)
    return tmp_path


def test_benchmark_scene_loads():
    scene = load_scene(BENCHMARK)
    assert scene.fibers.num_strands == 640
    assert scene.camera.type == "orthographic" and scene.camera.resolution == (256, 256)
    assert scene.camera.width == 1.0 and scene.camera.fov is None
    assert len(scene.lights) == 2
    sun, sky = scene.lights
    assert isinstance(sun, DirectionalLight) and isinstance(sky, EnvironmentLight)
    np.testing.assert_allclose(sun.direction, np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0]))
    assert sky.radiance == (0.3, 0.3, 0.3) and sky.image is None
    assert scene.hair.colour_input == "sigma_a"
    np.testing.assert_array_equal(scene.hair.absorption, [0.1444, 0.2491, 0.516])
    assert scene.render == RenderSettings(spp=64, max_depth=16, seed=0)
    assert scene.card is None
    assert scene.path == BENCHMARK.resolve()
    assert Path(scene.source["fibers"]["file"]) == BENCHMARK.parent.resolve() / "standard_swatch_fibers.txt"
    json.dumps(scene.source)  # the source goes into image metadata as JSON


def test_dict_scene_equals_its_toml_twin(scene_dir):
    from_file = load_scene(scene_dir / "scene.toml")
    from_dict = scene_from_dict(SCENE_DICT, base_dir=scene_dir)
    for name in ("camera", "lights", "hair", "render", "card", "source"):
        assert getattr(from_file, name) == getattr(from_dict, name), name
    for name in ("points", "radii", "strand_offsets"):
        np.testing.assert_array_equal(getattr(from_file.fibers, name), getattr(from_dict.fibers, name))
    assert from_file.path == (scene_dir / "scene.toml").resolve() and from_dict.path is None


def test_scene_parts(scene_dir):
    scene = load_scene(scene_dir / "scene.toml")
    assert scene.camera == Camera(
        type="perspective", origin=(0, 0.5, 4), target=(0, 0, 0), up=(0, 1, 0), fov=30, resolution=(64, 48)
    )
    sun, sky = scene.lights
    assert sun == DirectionalLight(direction=(0, 0, -1), irradiance=(1, 2, 3))
    assert sky.file == (scene_dir / "sky.exr").resolve() and sky.radiance is None
    np.testing.assert_array_equal(sky.image, 2.0 * SKY)
    assert sky.image.dtype == np.float32
    assert scene.source["lights"][1]["file"] == str(sky.file)
    assert scene.fibers.num_strands == 12
    assert scene.hair.albedo == (0.6, 0.4, 0.2) and scene.hair.beta_m == 0.25
    assert scene.render == RenderSettings(spp=4, seed=7) and scene.render.max_depth == 64
    assert scene.card == Card(albedo=(0.5, 0.5, 0.5), distance=0.05)


def test_fibers_from_a_file(scene_dir):
    data = copy.deepcopy(SCENE_DICT)
    data["fibers"] = {"file": "fibers.txt"}
    scene = scene_from_dict(data, base_dir=scene_dir)
    assert scene.fibers.num_strands == 6
    assert scene.source["fibers"]["file"] == str((scene_dir / "fibers.txt").resolve())
    assert data["fibers"]["file"] == "fibers.txt"  # the caller's dict is left alone


def _edit(path, value):
    """A copy of SCENE_DICT with the key at `path` (a tuple of keys and indices) set to `value`, or removed when
    `value` is REMOVE."""
    data = copy.deepcopy(SCENE_DICT)
    *parents, last = path
    table = data
    for key in parents:
        table = table[key]
    if value is REMOVE:
        del table[last]
    else:
        table[last] = value
    return data


REMOVE = object()

BAD_SCENES = [
    # (what to change, new value, the message expected)
    (("camera", "widht"), 1.0, r"scene.toml: [camera] unknown key(s) ['widht']"),
    (("camera", "width"), 1.0, r"scene.toml: [camera] width does not apply to perspective cameras"),
    (("camera", "fov"), "wide", r"scene.toml: [camera] fov must be a number, got 'wide'"),
    (("camera", "fov"), 0.0, r"scene.toml: [camera] fov must be in (0, 180) degrees, got 0.0"),
    (("camera", "fov"), 180, r"scene.toml: [camera] fov must be in (0, 180) degrees, got 180.0"),
    (("camera", "fov"), REMOVE, r"scene.toml: [camera] fov is required for perspective cameras"),
    (("camera", "type"), "fisheye", r"scene.toml: [camera] type must be one of"),
    (("camera", "origin"), [0.0, 1.0], r"scene.toml: [camera] origin must be three numbers, got [0.0, 1.0]"),
    (("camera", "up"), "y", r"scene.toml: [camera] up must be three numbers, got 'y'"),
    (("camera", "target"), [0.0, 0.5, 4.0], r"scene.toml: [camera] target must differ from origin"),
    (("camera", "up"), [0.0, -0.5, -4.0], r"scene.toml: [camera] up [0.0, -0.5, -4.0] must not be parallel"),
    (("camera", "up"), [0, 0, 0], r"scene.toml: [camera] up must be a nonzero vector"),
    (("camera", "resolution"), [256], r"scene.toml: [camera] resolution must be two positive integers, got [256]"),
    (("camera", "resolution"), [256, 0], r"scene.toml: [camera] resolution must be two positive integers"),
    (("camera", "resolution"), [256.0, 256], r"scene.toml: [camera] resolution must be two positive integers"),
    (("camera", "origin"), REMOVE, r"scene.toml: [camera] missing key(s) ['origin']"),
    (("camera",), REMOVE, r"scene.toml: the [camera] table is missing"),
    (("camera",), 3, r"scene.toml: [camera] must be a table, got 3"),
    (("cameras",), {}, r"scene.toml: unknown table(s) ['cameras']"),
    (("lights",), [], r"scene.toml: no lights"),
    (("lights",), REMOVE, r"scene.toml: no lights"),
    (("lights",), {"type": "directional"}, r"scene.toml: lights must be an array of tables ([[lights]])"),
    (("lights", 0, "type"), "spot", r"scene.toml: [[lights]] #1 type must be one of ['directional', 'environment']"),
    (("lights", 0, "direction"), [0, 0, 0], r"scene.toml: [[lights]] #1 direction must be a nonzero vector"),
    (
        ("lights", 0, "irradiance"),
        [1, -1, 1],
        r"scene.toml: [[lights]] #1 irradiance must be three numbers in [0, 1e+12]",
    ),
    (("lights", 0, "radiance"), [1, 1, 1], r"scene.toml: [[lights]] #1 unknown key(s) ['radiance']"),
    (("lights", 1, "file"), "nowhere.exr", r"scene.toml: [[lights]] #2 file not found: "),
    (("lights", 1, "radiance"), [1, 1, 1], r"scene.toml: [[lights]] #2 needs exactly one of radiance"),
    (("lights", 1, "scale"), -1.0, r"scene.toml: [[lights]] #2 scale must be ≥ 0, got -1.0"),
    (
        ("lights",),
        SCENE_DICT["lights"] + [{"type": "environment", "radiance": [1, 1, 1]}],
        r"scene.toml: [[lights]] #3 is a second environment light; a scene has at most one",
    ),
    (("fibers",), {"file": "missing.txt"}, r"scene.toml: [fibers] file not found: "),
    (("fibers",), {"file": "fibers.txt", "count": 3}, r"scene.toml: [fibers] unknown key(s) ['count']"),
    (("fibers",), {}, r"scene.toml: [fibers] needs exactly one of file"),
    (("fibers", "generator"), "bald", r"scene.toml: [fibers] generator must be one of"),
    (("fibers", "curl"), 0.1, r"scene.toml: [fibers] generator 'wavy': unknown key(s) ['curl']"),
    (("fibers", "count"), 12.5, r"scene.toml: [fibers] generator 'wavy': count must be an integer, got 12.5"),
    (("fibers", "amplitude"), "big", r"scene.toml: [fibers] generator 'wavy': amplitude must be a number"),
    (("fibers", "amplitude"), -1.0, r"scene.toml: [fibers] generator 'wavy': amplitude must be a positive"),
    (("hair", "beta"), 0.3, r"scene.toml: [hair] unknown key(s) ['beta']; allowed: ['albedo',"),
    (("hair", "beta_m"), 1.5, r"scene.toml: [hair] beta_m = 1.5 is outside the allowed range [0.0, 1.0]"),
    (("hair", "albedo"), REMOVE, r"scene.toml: [hair] HairParams needs exactly one colour input"),
    (("render", "spp"), 1.5, r"scene.toml: [render] spp must be an integer, got 1.5"),
    (("render", "spp"), "64", r"scene.toml: [render] spp must be an integer, got '64'"),
    (("render", "spp"), 0, r"scene.toml: [render] spp must be at least 1, got 0"),
    (("render", "spp"), True, r"scene.toml: [render] spp must be an integer, got True"),
    (("render", "max_depth"), 0, r"scene.toml: [render] max_depth must be at least 1, got 0"),
    (("render", "seed"), -1, r"scene.toml: [render] seed must be at least 0, got -1"),
    (("render", "samples"), 4, r"scene.toml: [render] unknown key(s) ['samples']"),
    (("card", "albedo"), [0.5, 1.5, 0.5], r"scene.toml: [card] albedo must be three numbers in [0, 1]"),
    (("card", "distance"), 0.0, r"scene.toml: [card] distance must be in [1e-15, 1e+15] scene units, got 0.0"),
]


@pytest.mark.parametrize("path,value,message", BAD_SCENES, ids=[str(case[:2]) for case in BAD_SCENES])
def test_bad_scenes_name_the_table_and_key(scene_dir, path, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        scene_from_dict(_edit(path, value), base_dir=scene_dir, where="scene.toml")


def test_orthographic_camera_needs_width(scene_dir):
    camera = dict(SCENE_DICT["camera"], type="orthographic")
    with pytest.raises(ValueError, match=re.escape("[camera] fov does not apply to orthographic cameras")):
        scene_from_dict(dict(SCENE_DICT, camera=camera), base_dir=scene_dir, where="scene.toml")
    del camera["fov"]
    for width, problem in ((None, "width is required"), (0.0, "width must be > 0, got 0.0"), (-1, "width must be > 0")):
        if width is not None:
            camera["width"] = width
        with pytest.raises(ValueError, match=re.escape(f"scene.toml: [camera] {problem}")):
            scene_from_dict(dict(SCENE_DICT, camera=camera), base_dir=scene_dir, where="scene.toml")


def test_toml_syntax_error_names_the_file(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[camera]\ntype = orthographic\n")
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}: TOML syntax error: Invalid value \(at line 2"):
        load_scene(path)


def test_missing_scene_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing.toml: scene file not found"):
        load_scene(tmp_path / "nothing.toml")


def test_errors_name_the_scene_file(scene_dir):
    path = scene_dir / "scene.toml"
    path.write_text(SCENE_TOML.replace("resolution = [64, 48]", "resolution = [64]"))
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: \[camera\] resolution must be two positive"):
        load_scene(path)


def test_fiber_file_errors_propagate_with_the_table(scene_dir):
    (scene_dir / "bad.txt").write_text("0 0 0 0.1\n1 1 1\n")
    with pytest.raises(
        ValueError, match=r"^scene.toml: \[fibers\] file: .*bad.txt: line 2: strand 0: expected 4 numbers"
    ):
        scene_from_dict(_edit(("fibers",), {"file": "bad.txt"}), base_dir=scene_dir, where="scene.toml")
    (scene_dir / "fibers.obj").write_text("")
    with pytest.raises(ValueError, match=r"^scene.toml: \[fibers\] file: .*unknown fiber file extension '.obj'"):
        scene_from_dict(_edit(("fibers",), {"file": "fibers.obj"}), base_dir=scene_dir, where="scene.toml")


def test_bad_environment_image_names_the_light(scene_dir):
    (scene_dir / "sky.exr").write_text("not an image")
    with pytest.raises(ValueError, match=r"^scene.toml: \[\[lights\]\] #2 file: .*sky.exr: not an EXR file"):
        scene_from_dict(SCENE_DICT, base_dir=scene_dir, where="scene.toml")


def test_default_where_and_base_dir(scene_dir, monkeypatch):
    monkeypatch.chdir(scene_dir)
    assert scene_from_dict(SCENE_DICT).lights[1].file == (scene_dir / "sky.exr").resolve()
    with pytest.raises(ValueError, match=r"^scene: \[render\] spp must be at least 1"):
        scene_from_dict(_edit(("render", "spp"), 0))
