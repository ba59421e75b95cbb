"""The albedo inversion's coefficients (HairParams.albedo_inversion, [hair.albedo_inversion]) and `calibrate`.

The renders here are tiny (8×8 px, 32 spp, albedo standard errors about 0.01): the properties tested are
checked against the renders' own standard errors. The block is 80 layers deep: the talk's form
c = exp(−sqrt(σ_a) P(β_n)) describes a block deep enough that no light reaches its bottom; at 40 layers light
does at low β_n (requested 0.75 at β_n = 0.05 measures 0.71 at 40 layers, 0.74 at 80), and the fit to the
renders below misses them by up to 3.8 standard errors (χ²/dof 5.8).
"""

import dataclasses
import math
import tomllib
import warnings

import numpy as np
import pytest

from warp_hair.calibrate import (
    block_scene,
    environment_white,
    fit_inversion,
    measure_points,
    measured_pixels,
    predicted_albedo,
    white_radiance,
    write_calibrated_scene,
)
from warp_hair.cli import main
from warp_hair.model.params import TALK_ALBEDO_INVERSION, HairParams, check_albedo_inversion
from warp_hair.scene import DirectionalLight, load_scene, scene_from_dict

CUSTOM = (4.0, 3.0, -6.0, 2.0, 1.0, -0.5)  # positive over [0.01, 1], and far from the talk's polynomial
BETA_N = (0.05, 0.25, 0.45, 0.65, 0.85, 1.0)

BLOCK_TOML = """
[camera]
type = "orthographic"
origin = [0.0, 0.0, 2.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
width = 0.25
resolution = [8, 8]

[[lights]]
type = "environment"
radiance = [1.0, 1.0, 1.0]

[fibers]
generator = "swatch"   # a dense block: 80 layers, 80 fibers each
count = 6400
layers = 80
length = 2.0
segments = 1

[hair]
sigma_a = 0.1
beta_n = 0.5

[card]
albedo = [0.0, 0.0, 0.0]

[render]
spp = 32
max_depth = 1024
"""


def _polynomial(b, p):
    return sum(pk * b**k for k, pk in enumerate(p))


def test_fit_recovers_known_coefficients_exactly():
    """Albedos made by c = exp(−sqrt(σ_a) P(β_n)) give back P's coefficients, weighted or not."""
    sigma_a, beta_n = (a.ravel() for a in np.meshgrid([0.003, 0.05, 0.4], np.linspace(0.01, 1.0, 7)))
    albedo = np.exp(-np.sqrt(sigma_a) * _polynomial(beta_n, CUSTOM))
    np.testing.assert_allclose(fit_inversion(sigma_a, beta_n, albedo), CUSTOM, rtol=1e-9, atol=1e-9)
    stderr = np.random.default_rng(1).uniform(0.001, 0.01, albedo.size)
    np.testing.assert_allclose(fit_inversion(sigma_a, beta_n, albedo, stderr), CUSTOM, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(predicted_albedo(sigma_a, beta_n, CUSTOM), albedo, rtol=1e-12)


def test_fit_needs_six_distinct_beta_n():
    sigma_a, beta_n = np.meshgrid([0.01, 0.1], [0.1, 0.3, 0.5, 0.7, 0.9])
    with pytest.raises(ValueError, match="at least 6 distinct β_n"):
        fit_inversion(sigma_a, beta_n, np.exp(-np.sqrt(sigma_a) * 5.0))


def test_hair_params_use_their_own_coefficients():
    """σ_a = (ln c / P(β_n))² with P from the given coefficients (β_n floored at 0.01), by default the talk's."""
    albedo = np.array([0.3, 0.5, 0.8])
    for beta_n in (0.0, 0.2, 0.7, 1.0):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # β_n = 0 renders as the floor, with a warning
            custom = HairParams(albedo=albedo, beta_n=beta_n, albedo_inversion=CUSTOM)
            talk = HairParams(albedo=albedo, beta_n=beta_n)
        b = max(beta_n, 0.01)
        np.testing.assert_allclose(custom.absorption, (np.log(albedo) / _polynomial(b, CUSTOM)) ** 2, rtol=1e-12)
        np.testing.assert_allclose(
            talk.absorption, (np.log(albedo) / _polynomial(b, TALK_ALBEDO_INVERSION)) ** 2, rtol=1e-12
        )
    assert talk.albedo_inversion == TALK_ALBEDO_INVERSION
    # Changing a control keeps the inversion; it is no control itself.
    moved = custom.replace(beta_n=0.4)
    assert moved.albedo_inversion == CUSTOM and "albedo_inversion" not in custom.to_dict()


@pytest.mark.parametrize(
    "coefficients, message",
    [
        ((1.0, -2.0, 0.0, 0.0, 0.0, 0.0), r"P\(β_n\) = 0 at β_n = 0.5"),  # a root inside [0.01, 1]
        ((-1.0, 0.0, 0.0, 0.0, 0.0, 0.0), r"at β_n = 0.01"),  # negative everywhere
        ((5.0, 0.0, 0.0, 0.0, 0.0, -6.0), r"positive over all of \[0.01, 1.0\]"),  # root near the top end
        ((5.0, 1.0, 2.0), r"must be 6 numbers"),
        ([[5.969, -0.215, 2.532, -10.73, 5.574, 0.245]], r"must be 6 numbers"),  # nested: not flattened
        ((5.0, 1.0, 2.0, 0.0, math.nan, 0.0), r"albedo_inversion\[4\] must be finite"),
    ],
)
def test_bad_coefficients_are_rejected(coefficients, message):
    with pytest.raises(ValueError, match=message):
        check_albedo_inversion(coefficients)
    with pytest.raises(ValueError, match=message):
        HairParams(albedo=0.5, albedo_inversion=coefficients)


def test_scene_table_round_trips(tmp_path):
    text = BLOCK_TOML + f"\n[hair.albedo_inversion]\ncoefficients = {list(CUSTOM)}\n"
    path = tmp_path / "scene.toml"
    path.write_text(text)
    scene = load_scene(path)
    assert scene.hair.albedo_inversion == CUSTOM
    table = scene.hair.to_table()
    assert table["albedo_inversion"] == {"coefficients": list(CUSTOM)}
    assert HairParams.from_dict(table) == scene.hair
    # Without the table: the talk's, and to_table leaves it out.
    plain = scene_from_dict(tomllib.loads(BLOCK_TOML))
    assert plain.hair.albedo_inversion == TALK_ALBEDO_INVERSION and "albedo_inversion" not in plain.hair.to_table()


@pytest.mark.parametrize(
    "table, message",
    [
        ("coefficients = [6.0, -12.0, 0.0, 0.0, 0.0, 0.0]", r"scene.toml \[hair\]: albedo_inversion.coefficients = "),
        ("coefficients = [6.0]", r"albedo_inversion.coefficients must be 6 numbers"),
        ("values = [6.0, 0, 0, 0, 0, 0]", r"albedo_inversion takes one key, coefficients"),
    ],
)
def test_scene_table_errors_name_the_file_and_key(tmp_path, table, message):
    path = tmp_path / "scene.toml"
    path.write_text(BLOCK_TOML + f"\n[hair.albedo_inversion]\n{table}\n")
    with pytest.raises(ValueError, match=message):
        load_scene(path)


def test_calibrated_copy_keeps_the_scene_and_refuses_to_overwrite_it(tmp_path):
    fibers = tmp_path / "fibers.txt"
    fibers.write_text("0 -0.5 0 0.01\n0 0.5 0 0.01\n")
    source = tmp_path / "scene.toml"
    generated = BLOCK_TOML[BLOCK_TOML.index('generator = "swatch"') : BLOCK_TOML.index("segments = 1")]
    source.write_text(BLOCK_TOML.replace(generated + "segments = 1", 'file = "fibers.txt"  # kept comment'))
    (tmp_path / "out").mkdir()
    copy = write_calibrated_scene(source, tmp_path / "out" / "calibrated.toml", CUSTOM)
    assert "# kept comment" in copy.read_text()
    loaded = load_scene(copy)
    assert loaded.hair.albedo_inversion == CUSTOM
    assert np.array_equal(loaded.fibers.points, load_scene(source).fibers.points)
    before = source.read_text()
    with pytest.raises(ValueError, match="never overwrites"):
        write_calibrated_scene(source, source, CUSTOM)
    assert source.read_text() == before


def test_white_reference_and_measured_pixels():
    """A white Lambertian card facing the camera shows L under a sky of radiance L (also as a lat-long image)
    and E cos θ / π under a directional light of irradiance E at θ from its normal."""
    scene = block_scene(HairParams(albedo=0.5), layers=4, resolution=8)
    np.testing.assert_allclose(white_radiance(scene), [1.0, 1.0, 1.0])
    sun = DirectionalLight(direction=(0.0, -math.sin(0.5), -math.cos(0.5)), irradiance=(3.0, 2.0, 1.0))
    behind = DirectionalLight(direction=(0.0, 0.0, 1.0), irradiance=(5.0, 5.0, 5.0))
    lit = dataclasses.replace(scene, lights=[sun, behind])
    np.testing.assert_allclose(white_radiance(lit), np.array([3.0, 2.0, 1.0]) * math.cos(0.5) / math.pi, rtol=1e-6)
    normal = -scene.camera.frame()[0]
    np.testing.assert_allclose(environment_white(np.full((64, 128, 3), 2.0), normal), [2.0, 2.0, 2.0], rtol=2e-3)
    assert measured_pixels(scene).all()
    data = tomllib.loads(BLOCK_TOML)
    wide = scene_from_dict({**data, "camera": {**data["camera"], "width": 3.0}})
    covered = measured_pixels(wide)
    assert covered.any() and not covered.all()  # the block's sides are in view, with sky beyond them


def test_recovered_coefficients_reproduce_talk_renders_within_noise():
    """Renders made with the talk's inversion (requested albedo 0.3 and 0.75 at six β_n) are measured; the
    coefficients fitted to them give back each render's measured albedo within its standard error."""
    scene = scene_from_dict(tomllib.loads(BLOCK_TOML))
    points = [(float(HairParams(albedo=c, beta_n=b).absorption[0]), b) for b in BETA_N for c in (0.3, 0.75)]
    albedo, stderr = measure_points(scene, points, seed=3)
    sigma_a, beta_n = np.array(points).T
    coefficients = fit_inversion(sigma_a, beta_n, albedo, stderr)
    z = (albedo - predicted_albedo(sigma_a, beta_n, coefficients)) / stderr
    assert np.all(np.abs(z) < 3.5), z
    assert np.sum(z**2) / (len(z) - 6) < 3.0
    # And through HairParams: asking for the measured albedo with the fitted inversion gives back σ_a.
    recovered = [
        HairParams(albedo=c, beta_n=b, albedo_inversion=coefficients).absorption[0] for c, b in zip(albedo, beta_n)
    ]
    slope = 2 * sigma_a / (albedo * np.abs(np.log(albedo)))  # |dσ_a/dc| of the inversion
    assert np.all(np.abs(np.array(recovered) - sigma_a) < 1.1 * slope * 3.5 * stderr)


def test_calibrate_command(tmp_path, capsys):
    scene = tmp_path / "block.toml"
    scene.write_text(BLOCK_TOML)
    copy = tmp_path / "calibrated.toml"
    argv = ["calibrate", str(scene), "--sigma-a", "0.01", "0.1", "--beta-n", *map(str, BETA_N), "-o", str(copy)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "[hair.albedo_inversion]" in out and "chi2/dof" in out and f"wrote {copy}" in out
    fitted = load_scene(copy).hair.albedo_inversion
    printed = tomllib.loads(out[out.index("[hair.albedo_inversion]") : out.index("wrote")])
    assert printed["hair"]["albedo_inversion"]["coefficients"] == list(fitted)
    assert scene.read_text() == BLOCK_TOML


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--beta-n", "0.1", "0.2", "0.3"], "--beta-n needs at least 6 distinct values"),
        (["--beta-n", "0.1", "0.2", "0.3", "0.4", "0.5", "1.5"], "--beta-n 1.5 is outside the allowed range"),
        (["--sigma-a", "0", "0.1"], "--sigma-a 0: grid values must be finite and > 0"),
        (["-o", "SCENE"], "is the scene file itself"),
    ],
)
def test_calibrate_command_errors(tmp_path, capsys, extra, message):
    scene = tmp_path / "block.toml"
    scene.write_text(BLOCK_TOML.replace("resolution = [8, 8]", "resolution = [2, 2]").replace("spp = 32", "spp = 1"))
    extra = [str(scene) if e == "SCENE" else e for e in extra]
    if "--beta-n" not in extra:
        extra += ["--beta-n", *map(str, BETA_N)]
    if "--sigma-a" not in extra:
        extra += ["--sigma-a", "0.1"]
    assert main(["calibrate", str(scene), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warp-hair: error: ") and message in err, err
