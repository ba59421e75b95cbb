"""Tests of warp_hair.io: EXR round trips with metadata, other EXR layouts, clear errors, PNG output."""

import re

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from warp_hair.io import read_exr, write_exr, write_png


def _image(height=5, width=7, seed=0):
    rng = np.random.default_rng(seed)
    # Values no 16-bit float could hold, so that a float32 round trip is really checked.
    return (rng.uniform(0.0, 10.0, (height, width, 3)) * (1 + 1e-6)).astype(np.float32)


def _write_channels(path, channels, **attributes):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **attributes}
    # The bindings ignore numpy strides: every plane must be contiguous.
    channels = {name: np.ascontiguousarray(pixels) for name, pixels in channels.items()}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))


def test_float32_round_trip_with_metadata(tmp_path):
    image = _image()
    image[0, 0] = [np.inf, 0.0, 1e-30]  # radiance a renderer could produce; EXR keeps it
    metadata = {
        "warp_hair": {
            "scene": {"camera": {"resolution": [7, 5]}},
            "hair": {"albedo": [0.6, 0.4, 0.2]},
            "spp": 64,
            "seed": 0,
            "version": "0.1.0",
        },
        "note": "a plain string",
    }
    path = tmp_path / "image.exr"
    write_exr(path, image, metadata)
    read, read_metadata = read_exr(path)
    assert read.dtype == np.float32 and read.shape == (5, 7, 3)
    np.testing.assert_array_equal(read, image)
    assert read_metadata == metadata


def test_file_layout(tmp_path):
    path = tmp_path / "image.exr"
    image = _image()
    write_exr(path, image)
    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = exr.channels()
    assert sorted(channels) == ["B", "G", "R"]
    assert all(channel.type() == OpenEXR.FLOAT for channel in channels.values())
    assert exr.header()["compression"] == OpenEXR.ZIP_COMPRESSION
    # Row 0 of the array is the top scanline of the file (the first of the data window).
    np.testing.assert_array_equal(channels["G"].pixels, image[..., 1])
    assert read_exr(path)[1] == {}


def test_half_float_exr_is_readable(tmp_path):
    image = _image().astype(np.float16)
    path = tmp_path / "half.exr"
    _write_channels(path, {name: image[..., c] for c, name in enumerate("RGB")})
    read, _ = read_exr(path)
    assert read.dtype == np.float32
    np.testing.assert_array_equal(read, image.astype(np.float32))


def test_luminance_is_replicated_and_alpha_dropped(tmp_path):
    image = _image()
    _write_channels(tmp_path / "y.exr", {"Y": image[..., 0]})
    np.testing.assert_array_equal(read_exr(tmp_path / "y.exr")[0], np.repeat(image[..., :1], 3, axis=-1))
    alpha = np.ones(image.shape[:2], dtype=np.float32)
    _write_channels(tmp_path / "rgba.exr", {"R": image[..., 0], "G": image[..., 1], "B": image[..., 2], "A": alpha})
    np.testing.assert_array_equal(read_exr(tmp_path / "rgba.exr")[0], image)


def test_foreign_string_attributes_are_kept_raw(tmp_path):
    path = tmp_path / "image.exr"
    image = _image()
    _write_channels(path, {name: image[..., c] for c, name in enumerate("RGB")}, owner="a photographer")
    assert read_exr(path)[1] == {"owner": "a photographer"}


def test_missing_file(tmp_path):
    path = tmp_path / "absent.exr"
    with pytest.raises(FileNotFoundError, match=re.escape(f"{path}: no such EXR file")):
        read_exr(path)


def test_not_an_exr(tmp_path):
    path = tmp_path / "image.exr"
    path.write_bytes(b"P6\n1 1\n255\n\x00\x00\x00")
    with pytest.raises(ValueError, match=re.escape(f"{path}: not an EXR file")):
        read_exr(path)


def test_truncated_exr(tmp_path):
    path = tmp_path / "image.exr"
    write_exr(path, _image(64, 64))
    path.write_bytes(path.read_bytes()[:400])
    with pytest.raises(ValueError, match=re.escape(f"{path}: damaged or unsupported EXR file")):
        read_exr(path)


def test_no_colour_channels(tmp_path):
    path = tmp_path / "depth.exr"
    _write_channels(path, {"Z": _image()[..., 0]})
    with pytest.raises(ValueError, match=re.escape(f"{path}: no R, G, B or Y channels to read; the file has ['Z']")):
        read_exr(path)


def test_write_errors(tmp_path):
    with pytest.raises(ValueError, match=r"shape \(H, W, 3\).*got \(4, 4\)"):
        write_exr(tmp_path / "a.exr", np.zeros((4, 4)))
    with pytest.raises(ValueError, match=r"metadata key 'compression' is a standard EXR attribute"):
        write_exr(tmp_path / "a.exr", _image(), {"compression": "none"})
    with pytest.raises(ValueError, match=r"metadata 'shape' cannot be written as JSON"):
        write_exr(tmp_path / "a.exr", _image(), {"shape": np.zeros(2)})
    with pytest.raises(OSError, match=r"cannot write the EXR file"):
        write_exr(tmp_path / "no_such_folder" / "a.exr", _image())


def test_png_is_tone_mapped_srgb(tmp_path):
    image = np.zeros((3, 5, 3), dtype=np.float32)
    image[0, 0] = [0.0, 0.5, 1.0]
    image[1, 0] = [2.0, np.nan, 0.001]
    image[2, 4] = [0.25, 0.25, 0.25]
    path = tmp_path / "image.png"
    write_png(path, image, exposure=2.0)
    with Image.open(path) as png:
        assert png.format == "PNG" and png.mode == "RGB" and png.size == (5, 3)
        pixels = np.asarray(png)
    # sRGB(0.5) = 0.7354 → 188; exposure 2 takes 0.25 there too; 0.002 is on the linear toe: 12.92 × 0.002.
    assert pixels[0, 0].tolist() == [0, 255, 255]
    assert pixels[1, 0].tolist() == [255, 0, round(255 * 12.92 * 0.002)]
    assert pixels[2, 4].tolist() == [188, 188, 188]
