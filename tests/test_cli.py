"""The `warp-hair` command line and the lobe profiles behind `warp-hair plot-bsdf`."""

import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.scenes import TINY_SCENE

import warp_hair as wh
from warp_hair.cli import main
from warp_hair.plot import azimuthal_profile, longitudinal_profile

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
FIGURE_PIXELS = (1440, 840)  # 12 × 7 inches at 120 dpi


def png_size(path):
    """(width, height) from the IHDR chunk, which a valid PNG has right after its signature."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


@pytest.mark.parametrize(
    "controls",
    [[], ["--eumelanin", "1.3", "--beta-n", "0.2", "--h", "0.3", "--theta-o", "-20", "45"]],
    ids=["defaults", "melanin-fixed-h"],
)
def test_plot_bsdf_writes_png(tmp_path, capsys, controls):
    out = tmp_path / "lobes.png"
    assert main(["plot-bsdf", "-o", str(out), *controls]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert out.stat().st_size > 10_000
    assert png_size(out) == FIGURE_PIXELS


def test_bad_control_exits_2_without_traceback(tmp_path):
    """Through the real entry point: exit status 2 and one line naming the control and its range."""
    result = subprocess.run(
        [sys.executable, "-m", "warp_hair.cli", "plot-bsdf", "-o", str(tmp_path / "x.png"), "--beta-m", "2"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "warp-hair: error: beta_m = 2.0 is outside the allowed range [0.0, 1.0]" in result.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize(
    "arguments,message",
    [
        (["--albedo", "0.5", "0.4"], "albedo must be one number or three"),
        (["--albedo", "0.5", "--sigma-a", "0.1"], "exactly one colour input"),
        (["--eta", "1.0"], "eta = 1.0 is outside the allowed range"),
        (["--theta-o", "0", "95"], "theta_o = 95.0 is outside the allowed range (-90, 90)"),
        (["--h", "1.5"], "h = 1.5 is outside the allowed range [-1, 1]"),
        (["-o", "missing-dir/lobes.png"], "directory 'missing-dir' does not exist"),
        (["-o", "lobes.jpg"], "must be a .png file"),
    ],
)
def test_bad_input_is_an_error_message(tmp_path, monkeypatch, capsys, arguments, message):
    monkeypatch.chdir(tmp_path)
    argv = ["plot-bsdf", *arguments] if "-o" in arguments else ["plot-bsdf", "-o", "lobes.png", *arguments]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("warp-hair: error: ") and message in err
    assert list(tmp_path.iterdir()) == []


def test_malformed_arguments_are_argparse_errors(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["plot-bsdf", "-o", "lobes.png", "--beta-m", "rough"])
    assert exit_info.value.code == 2
    assert "warp-hair plot-bsdf: error: argument --beta-m: invalid float value: 'rough'" in capsys.readouterr().err


def albedo_of(theta_i, lobes):
    """∫ (per lobe) cos θ_i dθ_i over the profile's midpoint grid in θ_i: dω = cos θ dθ dφ."""
    return (lobes * np.cos(theta_i)[:, None]).sum(axis=0) * np.pi / len(theta_i)


@pytest.mark.parametrize("beta_m,beta_n", [(0.3, 0.3), (0.1, 0.05), (0.8, 0.9)])
@pytest.mark.parametrize("theta_o", [0.0, 35.0, -70.0])
def test_white_fiber_longitudinal_profile_integrates_to_one(beta_m, beta_n, theta_o):
    """σ_a = 0: the fiber scatters everything, so ∫∫ S cos θ_i dθ_i dφ_i = 1, far field and at one offset."""
    params = wh.HairParams(sigma_a=0.0, beta_m=beta_m, beta_n=beta_n)
    for h in (None, 0.6):
        assert albedo_of(*longitudinal_profile(params, theta_o, h)).sum() == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("theta_o", [10.0, 55.0])
def test_each_lobe_integrates_to_its_attenuation(theta_o):
    """With absorption, lobe p of the far-field profile integrates to A_p averaged over h (its luminance)."""
    params = wh.HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.25, beta_n=0.2)
    wo = np.array([np.sin(np.radians(theta_o)), np.cos(np.radians(theta_o)), 0.0])
    h = -1.0 + (np.arange(4096) + 0.5) / 2048.0
    expected = wh.bsdf.attenuation(params, wo, h).astype(np.float64).mean(axis=0) @ np.array([0.2126, 0.7152, 0.0722])
    assert albedo_of(*longitudinal_profile(params, theta_o)) == pytest.approx(expected, rel=0.01, abs=1e-4)


def test_far_field_azimuthal_profile_is_mirror_symmetric():
    """Offsets h and −h scatter into mirrored azimuths, so their average is even in Δφ; one offset is not."""
    params = wh.HairParams(albedo=[0.6, 0.4, 0.2], beta_n=0.2)
    _, far = azimuthal_profile(params, 30.0)
    np.testing.assert_allclose(far, far[::-1], rtol=1e-3, atol=1e-6)
    _, near = azimuthal_profile(params, 30.0, h=0.5)
    assert not np.allclose(near, near[::-1], rtol=0.1)


def test_render_writes_exr_with_metadata_and_png(tiny_scene, tmp_path, capsys):
    scene = tiny_scene
    exr, png = tmp_path / "tiny.exr", tmp_path / "tiny.png"
    assert main(["render", str(scene), "-o", str(exr), "--png", str(png), "--spp", "3", "--threads", "1"]) == 0
    assert f"wrote {exr}" in capsys.readouterr().out
    image, metadata = wh.io.read_exr(exr)
    assert image.shape == (8, 12, 3) and np.isfinite(image).all() and image.max() > 0.0
    made = metadata["warp_hair"]
    assert made["spp"] == 3 and made["seed"] == 4 and made["hair"]["eumelanin"] == 1.3
    np.testing.assert_allclose(made["sigma_a"], wh.HairParams(eumelanin=1.3).absorption)
    assert png_size(png) == (12, 8)
    # The same scene and seed give the same image as the Python API.
    np.testing.assert_array_equal(image, wh.render(wh.load_scene(scene), spp=3))


def test_render_bad_scene_names_the_key(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text(TINY_SCENE.replace("resolution = [12, 8]", "resolution = [12]"))
    assert main(["render", str(scene), "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml: [camera] resolution must be two positive integers, got [12]" in err
    assert not (tmp_path / "x.exr").exists()


def test_warps_log_level_is_the_hosts(tmp_path):
    """A library leaves its host's settings alone: importing warp_hair (and optimize) keeps Warp's log level, and
    the command, run inside a program, quiets Warp only while it runs."""
    code = (
        "import warp as wp; wp.config.log_level = wp.LOG_DEBUG; "
        "import warp_hair, warp_hair.torch, optimize.fit; from warp_hair.cli import main; "
        "levels = [wp.config.log_level]; "
        f"main(['render', {str(tmp_path / 'missing.toml')!r}, '-o', {str(tmp_path / 'x.exr')!r}]); "
        "levels.append(wp.config.log_level); print(levels == [wp.LOG_DEBUG] * 2)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert out.stdout.strip().splitlines()[-1] == "True"


def test_the_command_leaves_out_warps_own_messages(tiny_scene, tmp_path):
    """Through the installed entry point (optimize.cli:main): on a machine without a GPU Warp's native library
    prints "Could not find or load the NVIDIA CUDA driver" when it starts, and Warp logs a banner and each module
    load; a command prints none of these, and --verbose brings them back."""

    def run(*flags):
        return subprocess.run(
            [sys.executable, "-m", "optimize.cli", *flags, "render", str(tiny_scene), "-o", str(tmp_path / "x.exr")],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).resolve().parents[1],
        )

    quiet = run()
    assert quiet.stdout.startswith("wrote ")
    for line in ("CUDA driver", "Warp ", "Module "):
        assert line not in quiet.stdout + quiet.stderr
    verbose = run("--verbose")
    assert "initialized" in verbose.stdout and "Module warp_hair" in verbose.stdout + verbose.stderr


def test_only_the_no_driver_line_is_dropped(capfd):
    """Warp's other native messages (a driver too old, an error) still reach the user."""
    from warp_hair.devices import NO_DRIVER_LINE, native_stderr_without

    with native_stderr_without(NO_DRIVER_LINE):
        os.write(2, f"Warp CUDA warning: {NO_DRIVER_LINE}. GPU execution will not be available.\n".encode())
        os.write(2, b"Warp CUDA error: Warp requires CUDA driver 12.0 or higher\n")
    assert capfd.readouterr().err == "Warp CUDA error: Warp requires CUDA driver 12.0 or higher\n"
