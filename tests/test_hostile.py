"""Hostile input: each reproducer of the hostile-input report gives a clear error naming the input, or a correct
image. Values that pass Python's checks but overflow in float32 or wrap in int32 are the theme."""

import copy
import json
import struct
import subprocess
import sys
import tomllib

import numpy as np
import pytest
import warp as wp
from helpers import reference_model as reference
from helpers.scenes import TINY_SCENE

import warp_hair as wh
from warp_hair import validate
from warp_hair.cli import main
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.formats import load_fibers, save_fibers
from warp_hair.geometry.generators import swatch
from warp_hair.io import write_exr
from warp_hair.model.params import HairParams
from warp_hair.scene import scene_from_dict

# The command-line tests' tiny scene: 12×8 pixels, 40 fibers, 2 spp.
BASE = tomllib.loads(TINY_SCENE)


def scene_with(path, value):
    data = copy.deepcopy(BASE)
    table = data
    for key in path[:-1]:
        table = table[key]
    table[path[-1]] = value
    return data


def image_of(data, **kwargs):
    return wh.render(scene_from_dict(data, where="scene.toml"), threads=1, **kwargs)


# Each: a path into the scene dict, the value, and what the error must say (file, table and key).
BAD = [
    (("render", "max_depth"), 2**31, "scene.toml: [render] max_depth must be at most 2147483647"),
    (("render", "spp"), 2**31, "scene.toml: [render] spp must be at most 2147483647"),
    (("render", "rr_depth"), 2**40, "scene.toml: [render] rr_depth must be at most 2147483647"),
    (("render", "seed"), 2**32, "scene.toml: [render] seed must be at most 4294967295"),
    (("camera", "origin"), [1e308, 1e308, 1e308], "scene.toml: [camera] origin must be at most 1e+15 in magnitude"),
    (("camera", "width"), 1e-300, "scene.toml: [camera] width must be in [1e-15, 1e+15] scene units"),
    (("camera", "resolution"), [2**16, 2**16], "scene.toml: [camera] resolution 65536x65536 has more than 2147483647"),
    (
        ("lights", 0, "irradiance"),
        [1e39, 1e39, 1e39],
        "scene.toml: [[lights]] #1 irradiance must be three numbers in [0, 1e+12]",
    ),
    (("hair", "eta"), 1e300, "scene.toml: [hair] eta = 1e+300 is outside the allowed range (1.0, 10.0]"),
    (
        ("hair", "r_roughness_scale"),
        1e-300,
        "r_roughness_scale = 1e-300 is outside the allowed range [1e-06, 1000000.0]",
    ),
    (("hair", "beta_m"), "0.3", "scene.toml: [hair] beta_m must be a number, got '0.3'"),
    (("hair", "beta_m"), True, "scene.toml: [hair] beta_m must be a number, got True"),
    (("hair", "eumelanin"), False, "scene.toml: [hair] eumelanin must be a number, got False"),
    (
        ("fibers", "jitter"),
        [0.1, 0.1],
        "scene.toml: [fibers] generator 'swatch': jitter must be a number, got [0.1, 0.1]",
    ),
    (("fibers", "radius"), [0.1, 0.1, 0.1], "generator 'swatch': radius must be a number, got [0.1, 0.1, 0.1]"),
    (("fibers", "segments"), 2**31, "generator 'swatch': segments must be at most 2147483647"),
    (("fibers", "segments"), 2**63 - 1, "generator 'swatch': segments must be at most 2147483647"),
    (("fibers", "count"), 10**12, "generator 'swatch': count must be at most 2147483647"),
    (("fibers", "count"), 2**30, "generator 'swatch': 1073741824 fibers of 8 segments make 9663676416 vertices"),
    (("fibers", "length"), 1e300, "position"),
    (("fibers", "radius"), 1e-9, "3e+09 times its thinnest fiber radius 1e-09"),
]


@pytest.mark.parametrize("path,value,message", BAD, ids=[f"{p[-1]}={v!r}"[:40] for p, v, _ in BAD])
def test_values_that_would_overflow_or_wrap_are_errors_naming_the_key(path, value, message):
    with pytest.raises(ValueError) as error:
        scene_from_dict(scene_with(path, value), where="scene.toml")
    assert message in str(error.value)
    assert str(error.value).startswith("scene.toml")


def test_the_scale_limit_names_the_ratio():
    with pytest.raises(
        ValueError,
        match=r"scene\.toml: the fibers and camera extend to 3 scene units from the origin, "
        r"3e\+06 times its thinnest fiber radius 1e-06",
    ):
        scene_from_dict(scene_with(("fibers", "radius"), 1e-6), where="scene.toml")


@pytest.mark.parametrize(
    "generator,args,message",
    [
        ("wavy", {"wavelength": 1e-308}, "wavelength = 1e-308 over length 1.4 needs inf segments per fiber"),
        ("wavy", {"wavelength": 1e-06}, "640 fibers of 16800000 segments make 10752000640 vertices, more than"),
        ("curly", {"pitch": 1e-300}, "pitch = 1e-300 over length 1.4 needs 2.24e+301 segments per fiber"),
        ("fur", {"segments": 10**12}, "segments must be at most 2147483647"),
    ],
)
def test_generator_sizes_are_checked_before_allocating(generator, args, message):
    data = scene_with(("fibers",), {"generator": generator, **args})
    with pytest.raises(ValueError) as error:
        scene_from_dict(data, where="scene.toml")
    assert str(error.value).startswith(f"scene.toml: [fibers] generator {generator!r}:")
    assert message in str(error.value)


def test_memory_error_says_how_much(monkeypatch):
    monkeypatch.setattr(validate, "available_memory", lambda: 2**30)
    with pytest.raises(
        ValueError,
        match=r"scene\.toml: \[fibers\] generator 'swatch': 10000000 fibers of 8 segments "
        r"\(90000000 vertices\) would take 10.7 GiB of memory, more than the 1 GiB available",
    ):
        scene_from_dict(scene_with(("fibers", "count"), 10**7), where="scene.toml")
    monkeypatch.setattr(validate, "available_memory", lambda: 100 * 2**10)
    with pytest.raises(ValueError, match=r"scene\.toml: rendering 320 fiber segments at 12x8 would take"):
        scene_from_dict(BASE, where="scene.toml")


def test_available_memory_is_positive_and_finite():
    assert 0 < validate.available_memory() < 2**63


@pytest.mark.parametrize("up", [[1e-320, 0.0, 0.0], [1e-200, 1e-200, 0.0], [1e300, 0.0, 0.0]])
def test_tiny_or_huge_up_vectors_give_the_frame_of_their_direction(up):
    """up's length does not matter, only its direction: the image is that of the unit vector."""
    unit = np.array(up) / np.abs(up).max()
    image = image_of(scene_with(("camera", "up"), up))
    reference = image_of(scene_with(("camera", "up"), (unit / np.linalg.norm(unit)).tolist()))
    assert np.isfinite(image).all() and image.max() > 0
    np.testing.assert_array_equal(image, reference)


def test_up_parallel_after_normalisation_is_an_error():
    with pytest.raises(ValueError, match=r"scene\.toml: \[camera\] up \[0\.0, 0\.0, 1e-320\] must not be parallel"):
        scene_from_dict(scene_with(("camera", "up"), [0.0, 0.0, 1e-320]), where="scene.toml")


def test_environment_radiance_beyond_the_limit(tmp_path):
    with pytest.raises(
        ValueError, match=r"scene\.toml: \[\[lights\]\] #2 radiance must be three numbers in \[0, 1e\+12\]"
    ):
        scene_from_dict(
            scene_with(("lights",), BASE["lights"] + [{"type": "environment", "radiance": [1e39] * 3}]),
            where="scene.toml",
        )
    write_exr(tmp_path / "sky.exr", np.ones((4, 8, 3), dtype=np.float32))
    light = {"type": "environment", "file": "sky.exr", "scale": 1e39}
    with pytest.raises(ValueError) as error:
        scene_from_dict(scene_with(("lights",), [light]), base_dir=tmp_path, where="scene.toml")
    assert str(error.value).startswith(
        f"scene.toml: [[lights]] #1 file: {tmp_path / 'sky.exr'} times scale 1e+39: "
        "radiance must be finite and in [0, 1e+12]"
    )


def test_render_checks_seed_and_spp_of_python_callers():
    scene = scene_from_dict(BASE)
    for kwargs, message in [
        ({"seed": 2**32}, "seed must be at most 4294967295"),
        ({"seed": -1}, "seed must be at least 0"),
        ({"spp": 2**31}, "spp must be at most 2147483647"),
        ({"spp": 2.0}, "spp must be an integer, got 2.0"),
    ]:
        with pytest.raises(ValueError, match=message):
            wh.render(scene, **kwargs)
    # The largest seed is a valid stream of its own, not a wrap to 0.
    assert not np.array_equal(wh.render(scene, seed=2**32 - 1, threads=1), wh.render(scene, seed=0, threads=1))


def test_python_built_scene_is_checked_at_render():
    scene = scene_from_dict(BASE)
    points = np.array(scene.fibers.points, dtype=np.float64) + 1e4
    scene.fibers = FiberAssembly(points, scene.fibers.radii, scene.fibers.strand_offsets)
    with pytest.raises(ValueError, match="times its thinnest fiber radius"):
        wh.render(scene)


# ---------------------------------------------------------------------------------------------------------------
# Fiber files


def test_far_vertex_and_huge_thickness_name_the_file_strand_and_vertex(tmp_path):
    path = tmp_path / "far.txt"
    path.write_text("# two strands\n0 0 0 0.01\n0 1 0 0.01\n\n1 0 0 0.01\n1 1 0 0.01\n1e30 0 0 0.01\n")
    with pytest.raises(
        ValueError, match=rf"{path}: line 7: strand 1, vertex 2: position \(1e\+30, 0.0, 0.0\) is beyond ±1e\+15"
    ):
        load_fibers(path)
    header = struct.pack("<4s4I5f88s", b"HAIR", 2, 6, 2, 2, 1e38, 0, 1, 1, 1, b"")
    (tmp_path / "thick.hair").write_bytes(header + np.zeros((6, 3), "<f4").tobytes())
    with pytest.raises(
        ValueError, match=r"thick\.hair: strand 0, vertex 0: radius 5e\+37 is outside \[1e-15, 1e\+15\]"
    ):
        load_fibers(tmp_path / "thick.hair")


def test_text_fiber_file_with_a_byte_order_mark_loads(tmp_path):
    fibers = swatch(count=3, layers=1, segments=2)
    save_fibers(fibers, tmp_path / "plain.txt")
    (tmp_path / "bom.txt").write_bytes(b"\xef\xbb\xbf" + (tmp_path / "plain.txt").read_bytes())
    loaded = load_fibers(tmp_path / "bom.txt")
    np.testing.assert_array_equal(loaded.points, load_fibers(tmp_path / "plain.txt").points)


def test_bytes_after_the_hair_data_are_an_error(tmp_path):
    save_fibers(swatch(count=3, layers=1, segments=2), tmp_path / "ok.hair")
    data = (tmp_path / "ok.hair").read_bytes()
    (tmp_path / "long.hair").write_bytes(data + b"\0" * 12)
    with pytest.raises(ValueError, match=r"long\.hair: 12 bytes after the data the header declares \(\d+ bytes\)"):
        load_fibers(tmp_path / "long.hair")


# ---------------------------------------------------------------------------------------------------------------
# Hair controls


@pytest.mark.parametrize(
    "controls,message",
    [
        ({"albedo": "0.5"}, "albedo[r] must be a number, got '0.5'"),
        ({"albedo": [0.5, True, 0.5]}, "albedo[g] must be a number, got True"),
        ({"albedo": 0.5, "beta_m": True}, "beta_m must be a number, got True"),
        ({"eumelanin": False}, "eumelanin must be a number, got False"),
        ({"albedo": 0.5, "eta": 3.5e38}, "eta = 3.5e+38 is outside the allowed range (1.0, 10.0]"),
        ({"albedo": 0.5, "r_roughness_scale": 1e-40}, "r_roughness_scale = 1e-40 is outside"),
        ({"albedo": 0.5, "r_roughness_scale": 1e40}, "r_roughness_scale = 1e+40 is outside"),
        ({"sigma_a": 1e300}, "sigma_a[r] = 1e+300 is outside the allowed range [0.0, 1e+30]"),
        ({"albedo": 0.5, "alpha": 10**400}, "alpha must be finite"),
    ],
)
def test_hair_params_are_strict(controls, message):
    with pytest.raises(ValueError) as error:
        HairParams(**controls)
    assert message in str(error.value)


# From the smallest η the range check accepts, the float32 just above 1 (an η whose float32 is 1, e.g.
# 1 + 1e-9, is an error: tests/test_inputs.py).
ETA_NEAR_ONE = [float(np.nextafter(np.float32(1.0), np.float32(2.0))), 1 + 1e-7, 1 + 1e-4]


def unit_rows(rng, n):
    w = rng.normal(size=(n, 3))
    return w / np.linalg.norm(w, axis=1, keepdims=True)


@pytest.mark.parametrize("eta", ETA_NEAR_ONE)
def test_eta_near_one_is_finite_and_matches_the_reference(eta):
    """η within a few float32 steps of 1: finite at grazing, and away from grazing (where the float64 reference
    is well conditioned) the same as the reference within test_reference_agreement's tolerance."""
    controls = {"albedo": [0.6, 0.4, 0.2], "eta": eta, "alpha": 0.0}
    params = HairParams(**controls)
    grazing = wh.bsdf.eval(params, [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], 0.3)
    assert np.isfinite(grazing).all() and (grazing >= 0).all()
    rng = np.random.default_rng(3)
    wo, wi = unit_rows(rng, 256), unit_rows(rng, 256)
    keep = np.abs(wo[:, 0]) < 0.9
    wo, wi = wo[keep], wi[keep]
    h = rng.uniform(-0.95, 0.95, len(wo))
    np.testing.assert_allclose(
        wh.bsdf.eval(params, wo, wi, h), reference.eval(controls, wo, wi, h), rtol=1e-4, atol=1e-6
    )
    w, weight, density = wh.bsdf.sample(
        params, np.repeat([[1.0, 0.0, 0.0]], 16, axis=0), 0.3, rng.uniform(size=(16, 3))
    )
    assert np.isfinite(w).all() and np.isfinite(weight).all() and np.isfinite(density).all()


def test_fresnel_guard_leaves_grazing_values_unchanged():
    """At exactly grazing wo the reflectance is 1 for every η > 1, which the guard returns without the formula."""
    controls = {"sigma_a": 0.3, "eta": 1.55, "alpha": 0.0}
    wo = np.repeat([[1.0, 0.0, 0.0]], 64, axis=0)
    wi = unit_rows(np.random.default_rng(4), 64)
    h = np.linspace(-0.9, 0.9, 64)
    np.testing.assert_allclose(
        wh.bsdf.eval(HairParams(**controls), wo, wi, h), reference.eval(controls, wo, wi, h), rtol=1e-4, atol=1e-6
    )


# ---------------------------------------------------------------------------------------------------------------
# truth.json


@pytest.mark.parametrize(
    "truth,message",
    [
        ({}, "truth.json: HairParams needs exactly one colour input"),
        ({"albedo": "0.5"}, "truth.json: albedo[r] must be a number, got '0.5'"),
        ({"albedo": 0.5, "beta_m": True}, "truth.json: beta_m must be a number, got True"),
        ({"albedo": 0.5, "beta": 0.3}, "truth.json"),
    ],
)
def test_truth_json_errors_name_the_file(tmp_path, truth, message):
    from optimize.target import read_truth

    path = tmp_path / "truth.json"
    path.write_text(json.dumps(truth))
    with pytest.raises(ValueError) as error:
        read_truth(path)
    assert message in str(error.value)


# ---------------------------------------------------------------------------------------------------------------
# Command line


@pytest.mark.parametrize(
    "options,replace,message",
    [
        (["--seed", "4294967296"], None, "--seed must be at most 4294967295, got 4294967296"),
        (["--seed", "-1"], None, "--seed must be at least 0, got -1"),
        (["--spp", "2147483648"], None, "--spp must be at most 2147483647"),
        (["--exposure", "nan", "--png", "PNG"], None, "--exposure must be finite, got nan"),
        (["--exposure", "-1", "--png", "PNG"], None, "--exposure must be > 0"),
        ([], ("max_depth = 8", "max_depth = 2147483648"), "[render] max_depth must be at most 2147483647"),
        ([], ("count = 40", "count = 1000000000000"), "count must be at most 2147483647"),
        ([], ("layers = 2", "layers = 2\nwavelength = 1e-308"), "generator 'swatch': unknown key(s) ['wavelength']"),
        ([], ('generator = "swatch"', 'generator = "wavy"\nwavelength = 1e-308'), "wavelength = 1e-308 over length"),
        ([], ("eumelanin = 1.3", 'eumelanin = "1.3"'), "[hair] eumelanin must be a number, got '1.3'"),
    ],
)
def test_cli_errors_exit_2_with_one_line(tmp_path, capsys, options, replace, message):
    scene = tmp_path / "tiny.toml"
    text = TINY_SCENE if replace is None else TINY_SCENE.replace(*replace)
    scene.write_text(text)
    options = [str(tmp_path / "x.png") if o == "PNG" else o for o in options]
    assert main(["render", str(scene), "-o", str(tmp_path / "x.exr"), *options]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warp-hair: error: ") and message in err and "Traceback" not in err
    assert not (tmp_path / "x.exr").exists() and not (tmp_path / "x.png").exists()


def test_unexpected_errors_are_short_unless_debug(tmp_path, capsys, monkeypatch):
    import warp_hair.scene

    def broken(*args, **kwargs):
        raise RuntimeError("something internal")

    monkeypatch.setattr(warp_hair.scene, "load_scene", broken)
    arguments = ["render", str(tmp_path / "tiny.toml"), "-o", str(tmp_path / "x.exr")]
    assert main(arguments) == 1
    err = capsys.readouterr().err
    assert "warp-hair: internal error: RuntimeError: something internal" in err and "report it" in err
    assert "Traceback" not in err
    assert main(["--debug", *arguments]) == 1
    assert "Traceback" in capsys.readouterr().err
    assert main([*arguments, "--debug"]) == 1
    assert "Traceback" in capsys.readouterr().err


@pytest.mark.parametrize(
    "command",
    [["render", "SCENE", "-o", "OUT"], ["gradcheck", "SCENE", "--spp", "256", "--params", "beta_m"]],
    ids=["render", "gradcheck"],
)
def test_ctrl_c_stops_within_a_second(tmp_path, command):
    """A real SIGINT to a real `warp-hair render` or `gradcheck`: no new tiles start, one line, exit 130, and no
    output file."""
    import signal
    import time

    scene = tmp_path / "slow.toml"
    # 4096 spp: one 256-pixel range would take seconds; ranges shrink with spp to stay short.
    scene.write_text(
        TINY_SCENE.replace("resolution = [12, 8]", "resolution = [160, 160]").replace("spp = 2", "spp = 4096")
    )
    out = tmp_path / "slow.exr"
    arguments = [{"SCENE": str(scene), "OUT": str(out)}.get(a, a) for a in command] + ["--threads", "2"]
    code = (
        "import signal, sys, threading, time, warp\n"
        # Python's own Ctrl-C handler, as in a terminal: a test runner started in the background inherits SIGINT
        # ignored, and its children with it.
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "from optimize.cli import main\n"
        "launch, said = warp.launch, threading.Event()\n"
        "def announced(*args, **kwargs):  # says when the first range is done: the render is under way\n"
        "    launch(*args, **kwargs)\n"
        "    if not said.is_set():\n"
        "        said.set(); print('RENDERING', flush=True)\n"
        "warp.launch = announced\n"
        f"code = main({arguments!r})\n"
        "print(time.monotonic(), flush=True)  # the interpreter's own teardown takes 0.2-2 s more\n"
        "sys.exit(code)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "RENDERING"
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out_text, err = proc.communicate(timeout=60)
        waited = float(out_text.split()[-1]) - sent  # CLOCK_MONOTONIC: the same clock in both processes
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "warp-hair: interrupted" and "Traceback" not in err
    assert waited < 1.5, f"took {waited:.1f} s to stop"
    assert not out.exists() and not any(p.name.startswith(".slow.exr") for p in tmp_path.iterdir())


@wp.kernel
def _count_kernel(out: wp.array(dtype=wp.int32), first: int):
    out[wp.tid() + first] = out[wp.tid() + first] + 1


def test_a_ctrl_c_inside_a_finalizer_is_raised_by_the_next_launch():
    """Python only prints an exception raised in a `__del__` (a Warp array's, freed between launches): a Ctrl-C
    landing there was lost, and the command ran on to its end (1 in 6 of the gradcheck case above). The command's
    handler keeps it pending instead; the next `launch_ranges` raises it, once."""
    import signal

    from warp_hair import parallel

    seen = []

    class Finalized:
        def __del__(self):
            try:
                parallel._interrupt(signal.SIGINT, sys._getframe())
                seen.append("kept")
            except KeyboardInterrupt:
                seen.append("raised")

    Finalized()  # collected at once
    assert seen == ["kept"]
    out = wp.zeros(6, dtype=wp.int32, device="cpu")
    with pytest.raises(KeyboardInterrupt):
        parallel.launch_ranges(_count_kernel, 6, [out], threads=2)
    assert out.numpy().tolist() == [0] * 6  # raised before any range ran
    parallel.launch_ranges(_count_kernel, 6, [out], threads=2)  # raised once: the next launch runs
    assert out.numpy().tolist() == [1] * 6
    with pytest.raises(KeyboardInterrupt):  # anywhere else, Python's own behaviour
        parallel._interrupt(signal.SIGINT, sys._getframe())


# ---------------------------------------------------------------------------------------------------------------
# Ctrl-C in a fit


def _tiny_target():
    from helpers.scenes import swatch_scene

    from optimize.target import Target, TargetImage

    scene = swatch_scene(
        {"albedo": [0.6, 0.4, 0.3], "beta_m": 0.3, "beta_n": 0.3},
        [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
        resolution=(8, 8),
        render_table={"spp": 8, "max_depth": 8, "seed": 1},
    )
    return Target("tiny", None, [TargetImage("front", scene, wh.render(scene, spp=8, seed=11), None, None)], None)


def _interrupting(monkeypatch, module, name, call):
    """Make `module.name` raise KeyboardInterrupt on its `call`-th call, as Ctrl-C there would."""
    original, calls = getattr(module, name), []

    def wrapper(*args, **kwargs):
        calls.append(1)
        if len(calls) == call:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, wrapper)


def test_ctrl_c_during_the_descent_returns_the_estimate_so_far(monkeypatch):
    """The mean of the iterates run (the last fifth, at least one), no refinement and no uncertainties."""
    import importlib

    from optimize import fit

    _interrupting(monkeypatch, importlib.import_module("optimize.fit"), "render_torch_pair", 4)
    result = fit(_tiny_target(), iters=10, spp=2, refine=2, progress=False)
    assert result.stop_reason == "interrupted" and result.iterations == 3
    assert result.uncertainties is None and result.history.refine == () and len(result.history.loss) == 3
    assert result.values["beta_m"] == result.history.values["beta_m"][-1]  # max(1, int(0.2 × 3)) = 1 iterate
    assert len(result.images) == 1 and np.all(np.isfinite(result.images[0]))


def test_ctrl_c_during_the_refinement_keeps_its_last_kept_step(monkeypatch):
    """The fit returns the end point of the last step kept (here both are) with the steps tried so far."""
    import importlib

    from optimize import fit

    _interrupting(monkeypatch, importlib.import_module("optimize.refine"), "linearize", 4)  # during the 3rd step
    result = fit(_tiny_target(), iters=4, spp=2, refine=6, progress=False)
    assert result.stop_reason == "interrupted" and result.iterations == 4 and result.uncertainties is None
    steps = result.history.refine
    assert len(steps) == 2
    kept = [step.values for step in steps if step.accepted]
    # Else the descent's estimate: its last iterate (max(1, int(0.2 × 4)) = 1 averaged).
    adam = {name: v[-1].tolist() if v.ndim == 2 else float(v[-1]) for name, v in result.history.values.items()}
    assert result.values == (kept[-1] if kept else adam)
