"""Photographs as targets: decoding (warp_hair.photo), the photos' gains and white balance (optimize/camera.py),
targets from photos (optimize/photo_target.py), and bad input."""

from __future__ import annotations

import io
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
from optimize.linearize import Linearization, linearize
from optimize.nuisance import Nuisance
from optimize.photo_target import camera_fov, downsample, horizontal_fov, make_photo_target
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


def test_exif_exposure_reads_the_exact_stop_where_apex_gives_it(tmp_path):
    """ExposureTime is the stop's rounded name (1/60 s for 2^-6 s): with ShutterSpeedValue and ApertureValue
    (APEX) beside it the exact stop is read; an APEX value more than a third of a stop from the name (an edited
    file) is not. write_photo's EXIF reads back through read_photo, PNG and JPEG."""
    named = {"ExposureTime": 1 / 60, "FNumber": 5.6, "ISOSpeedRatings": 200}
    exact = {**named, "ShutterSpeedValue": 6.0, "ApertureValue": 5.0}
    for suffix in (".png", ".jpg"):
        write_photo(tmp_path / f"named{suffix}", _linear(), exif=named)
        write_photo(tmp_path / f"exact{suffix}", _linear(), exif=exact)
        assert read_photo(tmp_path / f"named{suffix}").relative_exposure == pytest.approx(200 / 60 / 5.6**2, rel=1e-6)
        photo = read_photo(tmp_path / f"exact{suffix}")
        assert photo.exif["shutter_speed_value"] == pytest.approx(6.0)
        assert photo.relative_exposure == pytest.approx(200 * 2.0**-6 / 2.0**5, rel=1e-6)
    edited = {**exact, "ExposureTime": 1 / 125}  # 7 stops named, 6 in APEX: the name is read
    write_photo(tmp_path / "edited.jpg", _linear(), exif=edited)
    assert read_photo(tmp_path / "edited.jpg").relative_exposure == pytest.approx(200 / 125 / 2.0**5, rel=1e-6)
    with pytest.raises(ValueError, match="EXIF tag 'Flash' is not one warp-hair writes"):
        write_photo(tmp_path / "f.jpg", _linear(), exif={"Flash": 1})


def test_targets_photo_ties_the_gains_to_exif_when_told(tmp_path):
    """--gains exif makes a target whose one gain keeps the photos' EXIF ratios (from the EXRs' headers); by
    default a gain per photo, with a note where every photo has the EXIF to tie them (the lights' equality is the
    photographer's to say); --gains exif without EXIF is an error naming the photo."""
    image = np.full((32, 32, 3), 0.3, np.float32) + _gradient(32)
    write_photo(tmp_path / "front.jpg", image, exif={"ExposureTime": 1 / 60, "ShutterSpeedValue": 6.0, "FNumber": 8.0,
                                                     "ISOSpeedRatings": 100})  # fmt: skip
    write_photo(tmp_path / "back.jpg", image, exif={"ExposureTime": 1 / 500, "ShutterSpeedValue": 9.0, "FNumber": 8.0,
                                                    "ISOSpeedRatings": 100})  # fmt: skip
    write_photo(tmp_path / "plain.jpg", image)
    views = ["--light", "0.2,-0.3,-1", "--light", "0,-0.15,1", "--ortho-width", "0.4", "--resolution", "16"]
    both = ["--image", str(tmp_path / "front.jpg"), "--image", str(tmp_path / "back.jpg"), *views]
    lines = []
    make_photo_target(tmp_path / "default", photo_args(*both), log=lines.append)
    assert load_target(tmp_path / "default").gains == "per-image"
    assert any("every photo has its EXIF exposure" in line and "--gains exif" in line for line in lines)
    make_photo_target(tmp_path / "exif", photo_args(*both, "--gains", "exif"))
    target = load_target(tmp_path / "exif")
    assert target.gains == "exif" and np.allclose(camera.relative_exposures(target), [1.0, 1 / 8], rtol=1e-9)
    mixed = ["--image", str(tmp_path / "front.jpg"), "--image", str(tmp_path / "plain.jpg"), *views]
    lines = []
    make_photo_target(tmp_path / "mixed", photo_args(*mixed), log=lines.append)
    assert not any("every photo has its EXIF" in line for line in lines)
    with pytest.raises(ValueError, match=r"--gains exif: plain\.jpg has no EXIF exposure"):
        make_photo_target(tmp_path / "mixed2", photo_args(*mixed, "--gains", "exif"))
    assert not (tmp_path / "mixed2" / "plain.exr").exists()  # refused before its files are written


def test_a_target_made_from_photos_counts_their_codes_rounding(tmp_path):
    """The EXRs `targets photo` writes keep the photo's bits and block size, so the fit's χ² counts the 8-bit
    codes' rounding as it does for the photo read directly (it counted none before), over the photo pixels each
    target pixel averages."""
    from optimize.goodness import quantisation_variances

    write_photo(tmp_path / "front.png", np.full((32, 32, 3), 0.2, np.float32) + _gradient(32))
    views = ["--image", str(tmp_path / "front.png"), "--light", "0.2,-0.3,-1", "--ortho-width", "0.4"]
    make_photo_target(tmp_path / "made", photo_args(*views, "--resolution", "32"))
    made = load_target(tmp_path / "made")
    assert made.images[0].coding == (8, "srgb", 1.0) and made.images[0].photo is None
    direct = tmp_path / "direct"
    shutil.copytree(tmp_path / "made", direct)
    shutil.copy(tmp_path / "front.png", direct / "front.png")
    spec = direct / "target.toml"
    spec.write_text(spec.read_text().replace('image = "front.exr"', 'image = "front.png"'))
    read = load_target(direct)
    assert read.images[0].photo is not None
    settings = FitSettings()
    counted = quantisation_variances(made, settings)
    assert counted is not None and (counted > 0).all()
    assert np.allclose(counted, quantisation_variances(read, settings), rtol=1e-4)
    make_photo_target(tmp_path / "half", photo_args(*views, "--resolution", "16"))
    assert load_target(tmp_path / "half").images[0].coding == (8, "srgb", 4.0)


def test_a_runaway_gain_names_what_is_left_to_pin_it():
    """A gain the images cannot support: where EXIF ties the views already, the advice is a grey card, not EXIF."""
    from optimize.verdict import _camera

    report = {
        "gains": {"front": (10.8, 10.0)},
        "white_balance": {"value": [1.0, 1.0, 1.0], "sigma": [0.0, 0.0, 0.0]},
        "modes": {"gains": "exif", "white_balance": "fit"},
    }
    (reason,) = _camera(report)
    assert "a grey card in the shot" in reason and '"exif"' not in reason
    report["modes"]["gains"] = "per-image"
    (reason,) = _camera(report)
    assert 'gains = "exif"' in reason
    report["modes"]["gains"], report["cards"] = "exif", ["front"]
    (reason,) = _camera(report)
    assert "the grey card in view front is outweighed by the hair" in reason
    report["gains"], report["white_balance"]["value"] = {"front": (1.5, 0.1)}, [1.0, 1.0, 6.0]
    (reason,) = _camera(report)
    assert "white balance's b ran to 6" in reason and "the grey card in view front does not hold it" in reason


def test_bad_photos_are_clear_errors(tmp_path):
    codes = np.round(srgb_encode(_linear(32, 32)) * 255).astype(np.uint8)
    Image.fromarray(codes, "RGB").save(tmp_path / "whole.jpg", quality=90)
    data = (tmp_path / "whole.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut.jpg: damaged or truncated JPEG \(libjpeg: \"Premature end"):
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


def _targets_photo(capsys, tmp_path, image, *options, resolution=32):
    """`warp-hair targets photo` as a user runs it: (exit status, stdout, stderr)."""
    from optimize.cli import main

    out_dir = tmp_path / "made"
    rc = main(
        ["targets", "photo", str(out_dir), "--image", str(image), "--light", "0.2,-0.3,-1", "--ortho-width", "0.4"]
        + ["--resolution", str(resolution), *options]
    )
    out, err = capsys.readouterr()
    assert "internal error" not in err and "Traceback" not in err
    return rc, out, err


def _png_header(path, width, height, bit_depth=8, colour_type=2):
    """A PNG that declares its size in IHDR and holds (almost) nothing: what a decompression bomb's header says."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b"")
    )


def test_a_decompression_bomb_is_an_error_with_its_size_and_the_limit(tmp_path, capsys):
    _png_header(tmp_path / "bomb.png", 100000, 100000)
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "bomb.png")
    assert rc == 2
    assert (
        "bomb.png: the file declares a 100000x100000 image (10000 megapixels), more than warp-hair decodes (179 "
        "megapixels, MAX_PIXELS)" in err
    )


def test_a_jpeg_whose_compressed_data_libjpeg_finds_corrupt_is_an_error(tmp_path, capsys):
    """A restart marker's number flipped (FF D0 to FF D1) in the entropy-coded data: libjpeg warns and resyncs,
    Pillow drops the warning and decodes two thirds of the pixels wrong."""
    codes = np.round(srgb_encode(_linear(48, 64)) * 255).astype(np.uint8)
    Image.fromarray(codes).save(tmp_path / "whole.jpg", quality=90, restart_marker_blocks=4)
    data = bytearray((tmp_path / "whole.jpg").read_bytes())
    first = data.index(b"\xff\xd0", data.index(b"\xff\xda"))  # RST0, after the start of scan
    data[first + 1] = 0xD1
    (tmp_path / "flipped.jpg").write_bytes(data)
    with Image.open(tmp_path / "flipped.jpg") as im:  # Pillow alone: no word
        damaged = np.asarray(im.convert("RGB"))
    assert (np.abs(damaged.astype(int) - np.asarray(Image.open(tmp_path / "whole.jpg"))).max(-1) > 8).mean() > 0.3
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "flipped.jpg")
    assert rc == 2
    assert (
        'flipped.jpg: damaged or truncated JPEG (libjpeg: "Corrupt JPEG data: found marker 0xd1 instead of RST0")'
        in err
    )


def test_a_png_with_a_flipped_byte_is_an_error_where_pillow_decodes_it(tmp_path, capsys):
    """The image data's CRC is checked: the first byte of the deflate stream whose change Pillow decodes without
    a word (a changed image) is an error naming the chunk."""
    y, x = np.mgrid[0:48, 0:64]
    codes = np.stack([40 + 3 * x, 60 + 2 * y, 80 + x * y // 64], -1).astype(np.uint8)  # smooth: deflate's matches
    Image.fromarray(codes).save(tmp_path / "whole.png")
    data = (tmp_path / "whole.png").read_bytes()
    start = data.index(b"IDAT") + 6  # past the zlib header
    for k in range(start, start + 400):
        flipped = bytearray(data)
        flipped[k] ^= 0x10
        try:
            with Image.open(io.BytesIO(bytes(flipped))) as im:
                if not np.array_equal(np.asarray(im.convert("RGB")), codes):
                    break
        except (OSError, SyntaxError, ValueError):
            continue
    else:
        pytest.fail("Pillow caught every flip tried: the test has nothing to show")
    (tmp_path / "flipped.png").write_bytes(flipped)
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "flipped.png")
    assert (
        rc == 2 and "flipped.png: damaged, truncated or not a PNG file: ChunkError: Checksum error in IDAT chunk" in err
    )


@pytest.mark.parametrize("mode", ["1", "P"])
def test_a_bilevel_or_palette_png_is_an_error_naming_what_is_read(tmp_path, capsys, mode):
    y, x = np.mgrid[0:32, 0:32]
    codes = np.stack([4 * x, 4 * y, 2 * (x + y)], -1).astype(np.uint8)
    Image.fromarray(codes).convert(mode).save(tmp_path / "odd.png")
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "odd.png")
    assert rc == 2
    said = "a 1-bit greyscale PNG (black and white)" if mode == "1" else "a palette image"
    assert f"odd.png: {said}" in err
    if mode == "1":
        assert "warp-hair reads 8- or 16-bit RGB (or greyscale) PNG, JPEG and TIFF" in err


def test_16_bit_rgb_png_is_read_at_full_depth(tmp_path, capsys):
    """Codes a sixteenth of an 8-bit step apart come out as they are (Pillow keeps the top 8 bits)."""
    import png

    codes = (20000 + 16 * np.arange(48 * 64 * 3) % 4000).reshape(48, 64, 3).astype(np.uint16)
    png.Writer(64, 48, bitdepth=16, greyscale=False).write(
        (tmp_path / "deep.png").open("wb"), codes.reshape(48, -1).tolist()
    )
    rc, out, _ = _targets_photo(capsys, tmp_path, tmp_path / "deep.png", "--transfer", "linear", resolution=64)
    assert rc == 0 and "deep.png: PNG 16-bit, linear decoded" in out
    image, _ = read_exr(tmp_path / "made" / "deep.exr")
    assert np.abs(image - codes / 65535.0).max() < 1e-6


def test_transparency_is_an_error_and_an_opaque_alpha_channel_a_note(tmp_path, capsys):
    codes = np.round(srgb_encode(_linear(24, 32)) * 255).astype(np.uint8)
    rgba = np.dstack([codes, np.full((24, 32), 255, np.uint8)])
    Image.fromarray(rgba, "RGBA").save(tmp_path / "opaque.png")
    rc, out, _ = _targets_photo(capsys, tmp_path, tmp_path / "opaque.png")
    assert rc == 0 and "opaque.png: PNG 8-bit" in out and "alpha channel fully opaque: dropped" in out
    rgba[3, 5, 3] = 254
    Image.fromarray(rgba, "RGBA").save(tmp_path / "seen_through.png")
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "seen_through.png")
    assert rc == 2 and "seen_through.png: 1 of its 768 pixels are transparent or translucent" in err


def test_tiff_alpha_bilevel_and_inverted_grey(tmp_path, capsys):
    """A TIFF's alpha (ExtraSamples) follows the PNG's rule; 1-bit and MINISWHITE (inverted grey) are errors."""
    rgba = np.full((24, 32, 4), 40000, np.uint16)
    tifffile.imwrite(tmp_path / "opaque.tif", rgba | np.array([0, 0, 0, 65535], np.uint16), extrasamples=["unassalpha"])
    rc, out, _ = _targets_photo(capsys, tmp_path, tmp_path / "opaque.tif")
    assert rc == 0 and "opaque.tif: TIFF 16-bit" in out and "alpha channel fully opaque: dropped" in out
    tifffile.imwrite(tmp_path / "seen_through.tif", rgba, photometric="rgb", extrasamples=["unassalpha"])
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "seen_through.tif")
    assert rc == 2 and "seen_through.tif: 768 of its 768 pixels are transparent or translucent" in err
    tifffile.imwrite(tmp_path / "bilevel.tif", RNG.uniform(size=(24, 32)) > 0.5)
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "bilevel.tif")
    assert rc == 2 and "bilevel.tif: a 1-bit TIFF (black and white)" in err
    tifffile.imwrite(tmp_path / "inverted.tif", np.full((24, 32), 90, np.uint8), photometric="miniswhite")
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "inverted.tif")
    assert rc == 2 and "inverted.tif: a TIFF of photometric interpretation MINISWHITE" in err


def test_a_greyscale_photo_is_read_with_a_warning(tmp_path, capsys):
    codes = np.round(srgb_encode(_linear(24, 32)) * 255).astype(np.uint8)
    Image.fromarray(codes).convert("L").save(tmp_path / "grey.jpg", quality=95)
    rc, out, err = _targets_photo(capsys, tmp_path, tmp_path / "grey.jpg")
    assert rc == 0 and "greyscale: replicated to R = G = B" in out
    assert "warp-hair: warning: " in err and "grey.jpg: a greyscale photo" in err
    assert "the hair's colour cannot be fitted from it" in err


def test_each_view_says_how_many_pixels_are_clipped(tmp_path, capsys):
    linear = np.full((48, 64, 3), 0.3, np.float32)
    linear[:6, :8] = 2.0  # 48 clipped pixels
    linear[-4:, -4:] = 0.0  # 16 crushed
    write_photo(tmp_path / "front.png", linear)
    rc, out, _ = _targets_photo(capsys, tmp_path, tmp_path / "front.png")
    assert rc == 0
    assert "front.png: PNG 8-bit, srgb decoded; 48 clipped (1.56%) and 16 crushed (0.52%) of 3072 pixels" in out


def test_a_resolution_that_does_not_divide_the_photo_keeps_its_field(tmp_path, capsys):
    """A 64x40 photo at 48 across: blocks of 4/3 pixels spanning its whole width and height, so that its middle
    column and row (an edge in red and one in green) land in the target's middle, and every pixel counts once."""
    linear = np.full((40, 64, 3), 0.05, np.float32)
    linear[:, 32:] = 0.6
    linear[20:, :, 1] += 0.2
    write_photo(tmp_path / "halves.png", linear)
    photo = read_photo(tmp_path / "halves.png")
    rc, _, _ = _targets_photo(capsys, tmp_path, tmp_path / "halves.png", resolution=48)
    image, _ = read_exr(tmp_path / "made" / "halves.exr")
    assert rc == 0 and image.shape == (30, 48, 3)
    assert np.allclose(image[:, :24, 0], photo.image[0, 0, 0]) and np.allclose(image[:, 24:, 0], photo.image[0, -1, 0])
    assert np.allclose(image[:15, 0, 1], photo.image[0, 0, 1]) and np.allclose(image[15:, 0, 1], photo.image[-1, 0, 1])
    assert image.mean() == pytest.approx(photo.image.mean(), rel=1e-5)
    scene = load_target(tmp_path / "made").images[0].scene
    assert scene.camera.resolution == (48, 30) and scene.camera.width == 0.4
    # 41 rows: 30 rows of blocks fit, centred (a photo symmetric about its middle row gives a symmetric target).
    rows = np.abs(np.arange(41) - 20.0)[:, None, None] * np.ones((1, 64, 3))
    blocks, _ = downsample(rows, np.zeros((41, 64), bool), 48)
    assert blocks.shape == (30, 48, 3) and np.allclose(blocks, blocks[::-1])


def test_a_bad_resolution_or_mask_is_an_error_naming_it(tmp_path, capsys):
    write_photo(tmp_path / "front.png", np.full((48, 64, 3), 0.3, np.float32) + _gradient(64)[:48])
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "front.png", resolution=0)
    assert rc == 2 and "--resolution 0: must be between 1 and the photo's width, 64 pixels" in err
    Image.fromarray(np.full((10, 10), 255, np.uint8)).save(tmp_path / "small.png")
    rc, _, err = _targets_photo(capsys, tmp_path, tmp_path / "front.png", "--mask", str(tmp_path / "small.png"))
    assert rc == 2 and "small.png: the mask is 10x10 but its photo is 64x48" in err


def test_exif_orientations_match_pillows(tmp_path):
    from PIL import ImageOps

    codes = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    for orientation in range(1, 9):
        exif = Image.Exif()
        exif[0x0112] = orientation
        Image.fromarray(codes).save(tmp_path / f"o{orientation}.png", exif=exif)
        with Image.open(tmp_path / f"o{orientation}.png") as im:
            shown = np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
        assert np.array_equal(
            read_photo(tmp_path / f"o{orientation}.png").image, srgb_decode(shown / 255.0).astype(np.float32)
        )


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
            projection = Nuisance(T).projection(solved, target, weights, jacobians, (n,), columns)
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

    views = [SimpleNamespace(relative_exposure=e) for e in (0.01, 0.04)]
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


def _swatch_photo(tmp_path, name="swatch.png"):
    write_photo(tmp_path / name, np.full((40, 40, 3), 0.3, np.float32) + _gradient(40))
    return tmp_path / name


def test_a_wavy_clumpy_swatch_with_strays_is_a_recipe_the_fit_redraws(tmp_path, capsys):
    """--waves with a phase per layer, clumps and strays: the scene's [fibers] is that recipe, and target.toml says
    realisations = "random" (the photographed strands are not the scene's), which the target loads with and
    redraws: another realisation keeps the recipe and moves the strands."""
    from warp_hair.realisation import realisation

    rc, _, err = _targets_photo(
        capsys, tmp_path, _swatch_photo(tmp_path), "--waves", "0.012,0.25", "--phase-jitter", "0",
        "--layer-phase-jitter", "1", "--clumps", "12", "--clump-strength", "0.6", "--strays", "5", "--layers", "12",
        "--count", "456", "--stray-lift", "0.03", "--resolution", "16",
    )  # fmt: skip
    assert rc == 0, err
    target = load_target(tmp_path / "made")
    assert target.realisations == "random"
    assert "never the photographed strands" in (tmp_path / "made" / "target.toml").read_text()
    # How the strands lie, which a photo does not say: a prior over jitter, the layers' gap and places, and how far the
    # clumps close, the recipe's strength ± 0.2 (arrangement.py).
    assert target.arrangement.ranges == {
        "jitter": (0.05, 0.4),
        "layer_gap": (0.008, 0.015),
        "layer_shift_jitter": (0.0, 1.0),
        "clump_strength": (0.4, 0.8),
    }
    scene = target.images[0].scene
    fibers = scene.source["fibers"]
    assert {key: fibers[key] for key in ("generator", "amplitude", "wavelength", "phase_jitter")} == {
        "generator": "wavy", "amplitude": 0.012, "wavelength": 0.25, "phase_jitter": 0.0,
    }  # fmt: skip
    assert (fibers["layer_phase_jitter"], fibers["clumps"], fibers["clump_strength"]) == (1.0, 12, 0.6)
    assert (fibers["strays"], fibers["stray_lift"], fibers["layers"], fibers["segments"]) == (5, 0.03, 12, 128)
    assert scene.render.max_depth == 64  # twelve layers: the light's paths are longer
    other = realisation(scene, 1)
    assert other.source["fibers"]["clumps"] == 12 and other.source["fibers"]["strays"] == 5
    assert not np.allclose(other.fibers.points, scene.fibers.points)
    rc, _, _ = _targets_photo(capsys, tmp_path, _swatch_photo(tmp_path), "--rig", "flat", "--curls", "0.02,0.05")
    fibers = load_target(tmp_path / "made").images[0].scene.source["fibers"]
    assert (rc, fibers["generator"], fibers["segments"]) == (0, "curly", 160)  # 16 a turn over 0.5: not the flat 8
    assert load_target(tmp_path / "made").images[0].scene.render.max_depth == 32


@pytest.mark.parametrize(
    "options, message",
    [
        (["--clumps", "4", "--clump-strength", "2"], r"--clump-strength: clump_strength must be in \[0, 1\], got 2.0"),
        (["--clump-strength", "0.5"], r"--clump-strength: clump_strength needs clumps"),
        (["--strays", "200"], r"--strays: strays must be at most the front layer's 38 fibers"),
        (["--waves", "0,0.2"], r"--waves: amplitude must be a positive finite number, got 0.0"),
        (["--curls", "0.02,-1"], r"--curls: pitch must be a positive finite number, got -1.0"),
        (["--phase-jitter", "0.5"], r"--phase-jitter: the phases of waves or curls; give --waves or --curls"),
        (["--waves", "0.01,0.2", "--layer-phase-jitter", "3"], r"--layer-phase-jitter: layer_phase_jitter must be"),
        (["--rig", "fur", "--clumps", "3"], r"--clumps: the swatch rigs' \(draped, flat\), not --rig fur's"),
        (["--rig", "fur", "--fur-length", "-1"], r"--fur-length: length must be a positive finite number, got -1.0"),
    ],
)
def test_bad_fiber_flags_name_the_flag(tmp_path, capsys, options, message):
    import re

    rc, _, err = _targets_photo(capsys, tmp_path, _swatch_photo(tmp_path), *options)
    assert rc == 2 and re.search(message, err), err
    assert not (tmp_path / "made").exists()


@pytest.mark.parametrize(
    "options, message",
    [
        (["--waves", "0.01"], "argument --waves: expected two numbers AMPLITUDE,WAVELENGTH, got '0.01'"),
        (["--waves", "0.01,0.2", "--curls", "0.01,0.1"], "argument --curls: not allowed with argument --waves"),
    ],
)
def test_waves_take_two_numbers_and_exclude_curls(tmp_path, capsys, options, message):
    with pytest.raises(SystemExit) as exit_status:
        _targets_photo(capsys, tmp_path, _swatch_photo(tmp_path), *options)
    assert exit_status.value.code == 2 and message in capsys.readouterr().err


def test_an_hdri_is_checked_now_and_lights_every_view_with_the_given_lights(tmp_path, capsys):
    from warp_hair.io import write_exr

    photo = _swatch_photo(tmp_path)
    rc, _, err = _targets_photo(capsys, tmp_path, photo, "--hdri", str(tmp_path / "none.exr"))
    assert rc == 2 and "--hdri: " in err and "none.exr" in err and not (tmp_path / "made").exists()
    write_exr(tmp_path / "bad.exr", np.full((8, 16, 3), -1.0, np.float32))
    rc, _, err = _targets_photo(capsys, tmp_path, photo, "--hdri", str(tmp_path / "bad.exr"))
    assert rc == 2 and "bad.exr holds negative or non-finite radiance" in err
    write_exr(tmp_path / "sky.exr", np.full((8, 16, 3), 0.5, np.float32))
    rc, _, err = _targets_photo(capsys, tmp_path, photo, "--hdri", str(tmp_path / "sky.exr"))  # with its --light
    assert rc == 0, err
    lights = load_target(tmp_path / "made").images[0].scene.lights
    assert [type(light).__name__ for light in lights] == ["EnvironmentLight", "DirectionalLight"]
    assert lights[1].direction == pytest.approx(np.array([0.2, -0.3, -1]) / np.linalg.norm([0.2, -0.3, -1]))
