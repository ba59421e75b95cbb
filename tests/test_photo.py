"""Photographs as targets: decoding (warp_hair.photo), the photos' gains and white balance (optimize/camera.py),
targets from photos (optimize/photo_target.py), and bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile
import torch
from helpers.photo_args import photo_args
from PIL import Image, ImageCms

import targets
from optimize import camera
from optimize.fit import FitSettings
from optimize.linearize import Linearization, gain_projection, linearize
from optimize.photo_target import camera_fov, horizontal_fov, make_photo_target
from optimize.target import load_target
from warp_hair.io import read_exr, srgb_encode
from warp_hair.photo import read_photo, srgb_decode, write_photo

RNG = np.random.default_rng(5)


def _linear(h=12, w=16, top=0.9):
    return RNG.uniform(0.001, top, (h, w, 3)).astype(np.float32)


def test_srgb_decode_inverts_encode():
    x = np.linspace(0, 1, 1001)
    assert np.allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_photo_round_trip_and_clipping(tmp_path, suffix):
    """A smooth image (JPEG keeps those) with an 8×8 block over the top in red and one at zero red."""
    y, x = np.mgrid[0:48, 0:64] / 64.0
    linear = np.stack([0.05 + 0.6 * x, 0.1 + 0.5 * y, 0.3 + 0.2 * x * y], -1).astype(np.float32)
    linear[0:8, 8:16] = [1.5, 0.2, 0.2]  # clipped
    linear[8:16, 16:24] = [0.0, 0.3, 0.3]  # crushed
    path = tmp_path / f"p{suffix}"
    write_photo(path, linear)
    photo = read_photo(path)
    assert photo.transfer == "srgb" and photo.bits == 8 and photo.display_referred
    assert photo.clipped[2:6, 10:14].all()
    # JPEG: its ringing lifts a sixth of the black patch's codes above CRUSH_CODE_JPEG; lossless: all of it
    assert photo.crushed[9:15, 17:23].mean() > (0.75 if suffix == ".jpg" else 0.999)
    ok = ~(photo.clipped | photo.crushed)
    ok[:24, :32] = suffix == ".png"  # JPEG's colour (at half resolution) bleeds a block around the patches
    error = np.abs(photo.image[ok] - np.clip(linear, 0, 1)[ok])
    if suffix == ".png":  # half a code times the sRGB decoding curve's steepest slope, 2.4/1.055 at the top
        assert error.max() < 0.5 / 255 * 2.4 / 1.055 + 1e-6
    else:  # JPEG at quality 90 (its colour at half resolution): a code or two on average
        assert error.mean() < 0.01
    if suffix == ".png":  # lossless: clipped and crushed exactly there
        assert photo.clipped.sum() == 64 and photo.crushed.sum() == 64


def test_16_bit_rgb_tiff_linear_and_srgb(tmp_path):
    linear = _linear()
    codes = np.round(linear * 65535).astype(np.uint16)
    tifffile.imwrite(tmp_path / "lin.tif", codes, photometric="rgb")
    photo = read_photo(tmp_path / "lin.tif", transfer="linear")
    assert photo.bits == 16 and not photo.display_referred
    assert np.abs(photo.image - linear).max() < 1e-5
    assert read_photo(tmp_path / "lin.tif").transfer == "srgb"  # an untagged integer TIFF is display-referred


def test_16_bit_greyscale_tiff_is_read_as_grey_with_a_note(tmp_path):
    grey = np.round(RNG.uniform(0, 1, (8, 9)) * 60000).astype(np.uint16)
    tifffile.imwrite(tmp_path / "g.tif", grey)
    photo = read_photo(tmp_path / "g.tif", transfer="linear")
    assert np.allclose(photo.image[..., 0], grey / 65535.0, atol=1e-6)
    assert np.array_equal(photo.image[..., 0], photo.image[..., 2])
    assert any("greyscale" in note for note in photo.notes)


def test_icc_srgb_profile_and_exif(tmp_path):
    codes = np.round(srgb_encode(_linear()) * 255).astype(np.uint8)
    exif = Image.Exif()
    sub = exif.get_ifd(0x8769)
    sub[0x829A] = 1 / 125  # ExposureTime
    sub[0x829D] = 4.0  # FNumber
    sub[0x8827] = 200  # ISO
    sub[0x920A] = 50.0  # FocalLength
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.fromarray(codes, "RGB").save(tmp_path / "e.jpg", quality=95, exif=exif, icc_profile=icc)
    photo = read_photo(tmp_path / "e.jpg")
    assert photo.transfer == "srgb"
    assert photo.exif["exposure_time"] == pytest.approx(1 / 125) and photo.exif["iso"] == 200
    assert photo.relative_exposure == pytest.approx((1 / 125) * 200 / 16)
    # A fov contradicting the EXIF focal length is an error naming both; agreeing, the EXIF one is used.
    assert camera_fov(photo, sensor_width=36.0) == pytest.approx(horizontal_fov(50.0, 36.0))
    with pytest.raises(ValueError, match="contradicts the EXIF focal length 50"):
        camera_fov(photo, fov=60.0, sensor_width=36.0)


def test_bad_photos_are_clear_errors(tmp_path):
    codes = np.round(srgb_encode(_linear(32, 32)) * 255).astype(np.uint8)
    Image.fromarray(codes, "RGB").save(tmp_path / "whole.jpg", quality=90)
    data = (tmp_path / "whole.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut.jpg: damaged, truncated"):
        read_photo(tmp_path / "cut.jpg")
    Image.fromarray(codes, "RGB").convert("CMYK").save(tmp_path / "cmyk.jpg")
    with pytest.raises(ValueError, match="CMYK"):
        read_photo(tmp_path / "cmyk.jpg")
    Image.fromarray(codes, "RGB").convert("P").save(tmp_path / "pal.png")
    with pytest.raises(ValueError, match="palette"):
        read_photo(tmp_path / "pal.png")
    (tmp_path / "shot.cr2").write_bytes(b"II*\x00")  # a TIFF header and nothing more (tests/test_raw.py has the rest)
    with pytest.raises(ValueError, match=r"shot.cr2: damaged or truncated raw file"):
        read_photo(tmp_path / "shot.cr2")
    with pytest.raises(ValueError, match="transfer"):
        read_photo(tmp_path / "whole.jpg", transfer="gamma")


def _photo_target(tmp_path, name="cycles_brown_straight", kind="png", edit=None):
    """A copy of the shipped photo-like target made from `name` (benchmarks/make_photo_targets.py)."""
    source = targets.path(f"photo_{name.removeprefix('cycles_')}_{kind}")
    directory = tmp_path / source.name
    shutil.copytree(source, directory)
    if edit:
        edit(directory)
    return directory


def test_photo_target_loads_with_gains_and_mask(tmp_path):
    target = load_target(_photo_target(tmp_path))
    assert (target.gains, target.white_balance, target.origin) == ("per-image", "fit", "cycles")
    for image in target.images:
        left_out = image.photo.clipped | image.photo.crushed
        assert left_out.any() and not image.mask[left_out].any() and image.mask[~left_out].all()


def test_photo_target_bad_input(tmp_path):
    def all_clipped(directory):
        Image.fromarray(np.full((64, 64, 3), 255, np.uint8), "RGB").save(directory / "front.png")

    with pytest.raises(ValueError, match=r"front.png: every pixel is clipped"):
        load_target(_photo_target(tmp_path / "a", edit=all_clipped))

    def wrong_size(directory):
        Image.fromarray(np.full((40, 64, 3), 100, np.uint8), "RGB").save(directory / "front.png")

    with pytest.raises(ValueError, match=r"front.png: the image is 64x40 pixels but scene_front.toml's camera renders"):
        load_target(_photo_target(tmp_path / "b", edit=wrong_size))

    def exif_gains(directory):
        spec = directory / "target.toml"
        spec.write_text('gains = "exif"\n' + spec.read_text())

    with pytest.raises(ValueError, match=r'gains = "exif" but front.png has no EXIF exposure'):
        load_target(_photo_target(tmp_path / "c", edit=exif_gains))


def test_solve_recovers_gains_exactly():
    """T = G·I with G = g_k w_c: the alternating least squares finds g and w (green's w pinned to 1)."""

    class T:
        gains, white_balance, images = "per-image", "fit", [None, None]

    renders = [torch.rand(10, 10, 3, dtype=torch.float64) + 0.1 for _ in range(2)]
    g, w = np.array([1.7, 0.45]), np.array([1.08, 1.0, 0.93])
    references = [r * torch.from_numpy(gk * w) for r, gk in zip(renders, g)]
    scales = [float((t * t).mean()) for t in references]
    solved = camera.gains_for(T, [(r, r) for r in renders], references, [None, None], "l2", 2, scales)
    assert np.allclose(solved.g, g, rtol=1e-9) and np.allclose(solved.w, w, rtol=1e-9)


def test_projection_is_the_schur_complement():
    """The hair's curvature after projecting the gains' columns out equals the joint curvature's Schur
    complement: the loss minimised over the gains, its trade-offs with the hair counted."""
    n, p, q = 60, 3, 2
    a, c, w = RNG.normal(size=(n, p)), RNG.normal(size=(n, q)), RNG.uniform(0.5, 2, n)
    proj = camera.Projection(camera.Gains(np.ones(1), np.ones(3)), c, w, a, ["gain", "white_balance[r]"])
    projected = proj.apply(a)
    wa, wc = w[:, None] * a, w[:, None] * c
    joint = np.block([[a.T @ wa, a.T @ wc], [c.T @ wa, c.T @ wc]])
    schur = joint[:p, :p] - joint[:p, p:] @ np.linalg.inv(joint[p:, p:]) @ joint[p:, :p]
    assert np.allclose(projected.T @ (w[:, None] * projected), schur)
    assert np.allclose(c.T @ (w[:, None] * projected), 0, atol=1e-10)


def test_linearisation_at_the_truth_recovers_the_cameras_gains(tmp_path):
    """At the true hair, the gains solved from our renders are the ones the photo-like target was made with
    (its views auto-exposed, its white balance off by up to 8%), within the renderers' 0.5% disagreement and the
    8-bit JPEG's error."""
    directory = _photo_target(tmp_path, kind="jpeg")
    target = load_target(directory)
    truth = json.loads((directory / "camera_truth.json").read_text())
    hair = target.truth.to_dict()
    values = {"albedo": hair["albedo"], "beta_m": hair["beta_m"], "beta_n": hair["beta_n"]}
    lin = linearize(target, values, FitSettings(), spp=16, seed=3)
    gains = lin.camera.gains
    for k, image in enumerate(target.images):
        assert gains.g[k] == pytest.approx(truth["gains"][image.name], rel=0.03)
    assert np.allclose(gains.w, truth["white_balance"], rtol=0.02)
    # The projected residuals have nothing left along the gains' columns.
    cols = lin.camera.columns
    assert np.abs(cols.T @ (lin.loss_weights * lin.residuals.mean(0))).max() < 1e-9 * np.abs(cols).sum()


def _noisy_passes(rng, n, p, noise):
    """Three renders of a linear model at its truth (two passes and an earlier, independent one), their
    Jacobians, and a target with noise, all weighted as the loss weighs them."""
    truth = rng.uniform(0.2, 1.0, n)
    target = truth * (1 + noise * rng.normal(size=n))
    renders = truth * (1 + 0.05 * rng.normal(size=(3, n)))
    # Each control brightens some pixels more than others (a gain brightens all alike).
    shape = np.stack([np.linspace(0, 1, n) ** (k + 1) for k in range(p)], axis=1)
    jacobians = (shape * truth[:, None])[None] * (1 + 0.2 * rng.normal(size=(2, n, p)))
    return renders[:2] - target, jacobians, target, renders[2]


def test_gain_columns_from_an_independent_render_leave_no_lean_at_the_truth():
    """At the true controls the gradient of the loss minimised over the gains has mean zero, however noisy the
    target, when the gains' columns come from a render independent of the target and of both passes (refine.py's
    later steps). With the target's columns it holds −εᵀWε: a lean towards dimmer hair and brighter gains
    (docs/acceptance.md, "Photographs"), which this test must be able to see."""

    class T:
        gains, white_balance, images = "per-image", "fit", [type("I", (), {"name": "front"})()]

    rng = np.random.default_rng(7)
    n, p, draws = 300, 2, 400
    weights = np.full(n, 1.0 / n)
    solved = camera.Gains(np.ones(1), np.ones(3))
    gradients = {"render": [], "target": []}
    for _ in range(draws):
        residuals, jacobians, target, earlier = _noisy_passes(rng, n, p, noise=0.3)
        for source, columns in (("render", earlier), ("target", None)):
            projection = gain_projection(T, solved, target, weights, jacobians, (n,), columns)
            r = np.stack([projection.apply(x) for x in residuals])
            a = np.stack([projection.apply(x) for x in jacobians])
            assert np.abs(projection.columns.T @ (weights * r[0])).max() < 1e-12 * np.abs(projection.columns).max()
            lin = Linearization({}, r, np.zeros_like(r), a, [], weights, image_residuals=(n,))
            gradients[source].append(lin.gradient)
    unbiased, leaning = np.array(gradients["render"]), np.array(gradients["target"])
    assert np.all(np.abs(unbiased.mean(0)) < 4 * unbiased.std(0) / np.sqrt(draws))
    # The target's columns lean: the gradient along every control is positive (a dimmer hair looks better) by
    # more than 10 standard errors.
    assert np.all(leaning.mean(0) > 10 * leaning.std(0) / np.sqrt(draws))


def test_target_from_photos_in_one_command(tmp_path):
    """`warp-hair targets photo`'s maker: a photo of the Cycles brown swatch at 128 px becomes a 64 px target
    whose scenes match the shipped ones, with its clipped blocks masked."""
    image, _ = read_exr(targets.path("cycles_brown_straight") / "front.exr")
    big = np.repeat(np.repeat(image, 2, 0), 2, 1) * 2.2
    write_photo(tmp_path / "front.png", big)
    args = photo_args("--image", str(tmp_path / "front.png"), "--light", "0.2,-0.3,-1.0", "--ortho-width", "0.36")
    make_photo_target(tmp_path / "made", args)
    target = load_target(tmp_path / "made")
    assert (target.gains, target.white_balance) == ("per-image", "fit")
    made = target.images[0]
    assert made.image.shape == (64, 64, 3) and made.scene.camera.width == 0.36
    assert made.mask is not None and 0 < (~made.mask).sum() < 200
    clipped = read_photo(tmp_path / "front.png").clipped.reshape(64, 2, 64, 2).any(axis=(1, 3))
    assert np.array_equal(~made.mask, clipped)
    args.light = []
    with pytest.raises(ValueError, match="1 photo\\(s\\) but 0 --light"):
        make_photo_target(tmp_path / "other", args)


def test_exif_orientation_is_applied_with_a_note(tmp_path):
    """A camera's portrait JPEG is stored sideways with EXIF Orientation 6: read as a viewer shows it."""
    codes = np.zeros((4, 6, 3), np.uint8)
    codes[0, 0] = 200
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90° clockwise to view
    Image.fromarray(codes).save(tmp_path / "o.png", exif=exif)
    photo = read_photo(tmp_path / "o.png")
    assert photo.image.shape == (6, 4, 3) and photo.image[0, -1, 0] > 0.5
    assert photo.notes == ["EXIF Orientation 6 applied (the image as a viewer shows it)"]
    assert read_photo(tmp_path / "o.png").notes and not read_photo(_plain_png(tmp_path)).notes


def _plain_png(tmp_path):
    Image.fromarray(np.full((4, 6, 3), 90, np.uint8)).save(tmp_path / "plain.png")
    return tmp_path / "plain.png"


def test_exposure_is_not_fitted_on_top_of_the_gains(tmp_path):
    from optimize.fit import fit

    target = load_target(_photo_target(tmp_path))
    with pytest.raises(ValueError, match="its gains are fitted already"):
        fit(target, controls=("albedo", "exposure"), progress=False)


def test_exif_gains_keep_the_exposure_ratios():
    """gains = "exif": one gain times each view's t·ISO/N² over the first's; the views' ratio is not fitted."""
    from types import SimpleNamespace

    views = [SimpleNamespace(photo=SimpleNamespace(relative_exposure=e)) for e in (0.01, 0.04)]
    T = SimpleNamespace(gains="exif", white_balance="fit", images=views)
    renders = [torch.rand(8, 8, 3, dtype=torch.float64) + 0.1 for _ in range(2)]
    w = np.array([0.95, 1.0, 1.1])
    references = [r * torch.from_numpy(g * w) for r, g in zip(renders, (0.7, 2.8))]  # 4× apart, as EXIF says
    solved = camera.gains_for(T, [(r, r) for r in renders], references, [None, None], "l2", 1, [1.0, 1.0])
    assert np.allclose(solved.g, [0.7, 2.8], rtol=1e-9) and np.allclose(solved.w, w, rtol=1e-9)
    # With the second view really 5× the first, the ratio stays EXIF's 4 and the gain settles between.
    references[1] = references[1] * 1.25
    solved = camera.gains_for(T, [(r, r) for r in renders], references, [None, None], "l2", 1, [1.0, 1.0])
    assert solved.g[1] / solved.g[0] == pytest.approx(4.0) and 0.7 < solved.g[0] < 0.875


def test_fur_rig_with_a_perspective_camera_and_an_hdri(tmp_path):
    """The fur rig, a perspective camera from --fov, an HDRI for the light, a grey card: the scene written loads."""
    from warp_hair.io import write_exr

    write_exr(tmp_path / "sky.exr", np.full((8, 16, 3), 0.5, np.float32))
    write_photo(tmp_path / "fur.png", np.full((40, 40, 3), 0.3, np.float32) + _gradient(40))
    args = photo_args(
        "--image", str(tmp_path / "fur.png"), "--hdri", str(tmp_path / "sky.exr"), "--rig", "fur", "--count", "200",
        "--fiber-radius", "0.0015", "--fov", "8", "--resolution", "20", "--card", "0.18",
    )  # fmt: skip
    make_photo_target(tmp_path / "fur", args)
    scene = load_target(tmp_path / "fur").images[0].scene
    assert scene.camera.type == "perspective" and scene.camera.fov == 8.0 and scene.camera.resolution == (20, 20)
    assert type(scene.lights[0]).__name__ == "EnvironmentLight" and scene.card.albedo == (0.18, 0.18, 0.18)
    assert scene.camera.origin[2] == pytest.approx(1.5) and len(scene.fibers.radii) > 0


def _gradient(n):
    return (np.linspace(0, 0.4, n)[None, :, None] * np.ones((n, 1, 3))).astype(np.float32)
