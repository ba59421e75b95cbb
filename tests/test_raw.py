"""Camera raw (warp_hair.raw through warp_hair.photo.read_photo): real DNG files, written here with tifffile, read
back through LibRaw (rawpy) to the scene's linear sRGB, with their clipped and crushed pixels and EXIF."""

from __future__ import annotations

import shutil
import struct
import sys
from fractions import Fraction

import numpy as np
import pytest
import tifffile
from PIL import Image

import targets
from optimize.target import load_target
from warp_hair.io import read_exr
from warp_hair.photo import read_photo

# LibRaw's sRGB → XYZ (D65) table (LibRaw_constants::xyz_rgb, 0.21 and later): a DNG's ColorMatrix1 maps XYZ to
# the camera, and LibRaw multiplies it by this to get the camera's response to sRGB primaries.
XYZ_RGB = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
# An invented camera: its response to linear sRGB is diag(D) · M, M's rows summing to 1 (white gives D), so a
# neutral reads D (its AsShotNeutral) and white-balanced camera RGB is M · sRGB.
M = np.array([[0.80, 0.25, -0.05], [0.10, 0.85, 0.05], [0.02, 0.18, 0.80]])
D = np.array([0.55, 1.0, 0.72])
BLACK, WHITE = 512, 15000
RGGB = np.array([[0, 1], [1, 2]])
RNG = np.random.default_rng(22)


def _camera(srgb: np.ndarray) -> np.ndarray:
    """The camera's linear response (0 at black, 1 at the white level) to linear sRGB, (..., 3)."""
    return srgb @ (D[:, None] * M).T


def _expected(srgb: np.ndarray) -> np.ndarray:
    """What LibRaw's processing gives back: as-shot white balance scales channel c by 1/D_c, normalised so the
    largest multiplier is 1 (highlight mode "ignore"), i.e. by min(D)/D_c; the colour matrix then undoes M."""
    return D.min() * srgb


def _tolerance(white=WHITE, black=BLACK) -> float:
    """The worst error LibRaw's integer steps allow, in units of 1.0: the raw value's rounding here (half a
    sensor code, at most 65535/(white - black) output codes after the white balance's at most 1× scaling), the
    truncation of the scaled value (1 code) and of the two greens' mean (half a code), all through the colour
    matrix M⁻¹ (its rows' absolute sums), then the output's truncation (1 code); plus the ColorMatrix1
    rationals' precision (1e-6) and the difference between LibRaw's two shipped xyz_rgb tables (< 1e-5)."""
    per_channel = 0.5 * 65535 / (white - black) + 1.0 + 0.5
    rows = np.abs(np.linalg.inv(M)).sum(axis=1).max()
    return (rows * per_channel + 1.0) / 65535 + 2e-5


def _rationals(values, denominator=1_000_000) -> list:
    out = []
    for v in values:
        out += [round(v * denominator), denominator]
    return out


def _exif_ifd(offset: int, exposure, f_number, iso, focal, focal_35) -> bytes:
    """A little-endian Exif IFD placed at `offset` in the file: ExposureTime, FNumber, ISOSpeedRatings,
    FocalLength (RATIONALs after the entries) and FocalLengthIn35mmFilm."""
    entries = [
        (0x829A, 5, exposure),
        (0x829D, 5, f_number),
        (0x8827, 3, iso),
        (0x920A, 5, focal),
        (0xA405, 3, focal_35),
    ]
    data_at = offset + 2 + 12 * len(entries) + 4
    head, data = struct.pack("<H", len(entries)), b""
    for tag, kind, value in entries:
        if kind == 3:
            head += struct.pack("<HHIHH", tag, 3, 1, int(value), 0)
        else:
            head += struct.pack("<HHII", tag, 5, 1, data_at + len(data))
            exact = Fraction(value).limit_denominator(100_000)  # 1/60 s as 1/60, as cameras write it
            data += struct.pack("<II", exact.numerator, exact.denominator)
    return head + struct.pack("<I", 0) + data


def write_dng(path, sensels, *, black=BLACK, white=WHITE, orientation=1, exif=None, neutral=D):
    """A DNG 1.4 of uint16 `sensels`: (H, W) an RGGB mosaic (CFA), (H, W, 3) a demosaicked LinearRaw; the
    invented camera's ColorMatrix1 (for D65) and AsShotNeutral (`neutral`: a grey's camera reading, the
    camera's white D under D65); EXIF in its own IFD when given."""
    colour_matrix = (D[:, None] * M) @ np.linalg.inv(XYZ_RGB)
    tags = [
        (271, "s", 0, "warp-hair", True),
        (272, "s", 0, "test camera", True),
        (274, "H", 1, orientation, True),
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, "warp-hair test camera", True),  # UniqueCameraModel
        (50714, "H", 1, black, True),  # BlackLevel
        (50717, "I", 1, white, True),  # WhiteLevel
        (50721, "2i", 9, _rationals(colour_matrix.ravel()), True),  # ColorMatrix1: XYZ → camera
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1: D65
        (
            50728,
            "2I",
            3,
            _rationals(np.asarray(neutral) / max(neutral)),
            True,
        ),  # AsShotNeutral: a neutral's camera reading
    ]
    if sensels.ndim == 2:
        photometric = 32803  # CFA
        tags += [
            (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
            (33422, "B", 4, tuple(RGGB.ravel()), True),  # CFAPattern
            (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
            (50711, "H", 1, 1, True),  # CFALayout: rectangular
        ]
    else:
        photometric = 34892  # LinearRaw
    tifffile.imwrite(path, sensels, photometric=photometric, extratags=tags, metadata=None, subfiletype=0)
    if exif is not None:
        _add_exif(path, exif)


def _add_exif(path, exif) -> None:
    """Give the file's IFD0 an ExifIFD pointer (tifffile does not write one): IFD0's entries, plus the pointer,
    copied to the end of the file (their values stay where they are) and the header pointed at the copy, the
    Exif IFD after it."""
    data = bytearray(open(path, "rb").read())
    (ifd,) = struct.unpack_from("<I", data, 4)
    (count,) = struct.unpack_from("<H", data, ifd)
    entries = [bytes(data[ifd + 2 + 12 * k : ifd + 14 + 12 * k]) for k in range(count)]
    new_ifd = len(data) + len(data) % 2
    exif_at = new_ifd + 2 + 12 * (count + 1) + 4
    entries.append(struct.pack("<HHII", 34665, 4, 1, exif_at))
    entries.sort(key=lambda entry: struct.unpack_from("<H", entry)[0])
    data += b"\0" * (new_ifd - len(data)) + struct.pack("<H", len(entries)) + b"".join(entries) + b"\0" * 4
    data += _exif_ifd(exif_at, *exif)
    struct.pack_into("<I", data, 4, new_ifd)
    open(path, "wb").write(bytes(data))


def _mosaic(camera: np.ndarray, black=BLACK, white=WHITE) -> np.ndarray:
    """Sensels of an RGGB mosaic from per-sensel camera RGB (H, W, 3): each sensel keeps its colour's value."""
    height, width = camera.shape[:2]
    colour = RGGB[np.arange(height)[:, None] % 2, np.arange(width)[None, :] % 2]
    value = np.take_along_axis(camera, colour[..., None], -1)[..., 0]
    return np.round(black + value * (white - black)).astype(np.uint16)


def test_bayer_dng_decodes_to_the_scenes_linear_srgb(tmp_path):
    """Flat sRGB patches on quad boundaries: each half-size pixel is its quad's colour times min(D), within the
    integer steps' tolerance; the quads with a red sensel at the white level are clipped, those with a blue
    sensel below the black level crushed, nothing else; EXIF comes back; orientation 6 turns image and flags."""
    patches = RNG.uniform(0.05, 0.8, (6, 8, 3))
    scene = np.repeat(np.repeat(patches, 4, 0), 4, 1)  # (24, 32, 3): one colour per 4×4 quads
    sensels = _mosaic(_camera(np.repeat(np.repeat(scene, 2, 0), 2, 1)))  # (48, 64)
    sensels[10:15:2, 18:23:2] = WHITE  # red sensels (even, even) at white: quads [5:8, 9:12]
    sensels[31:36:2, 41:48:2] = BLACK - 3  # blue sensels (odd, odd) below black: quads [15:18, 20:24]
    exif = (1 / 125, 4.0, 200, 50.0, 75)
    write_dng(tmp_path / "shot.dng", sensels, exif=exif)
    photo = read_photo(tmp_path / "shot.dng")
    assert (photo.format, photo.transfer, photo.raw, photo.display_referred) == ("DNG raw", "linear", True, False)
    assert photo.camera_exposed and photo.image.shape == (24, 32, 3) and photo.image.dtype == np.float32
    clipped, crushed = np.zeros((24, 32), bool), np.zeros((24, 32), bool)
    clipped[5:8, 9:12] = True
    crushed[15:18, 20:24] = True
    assert np.array_equal(photo.clipped, clipped) and np.array_equal(photo.crushed, crushed)
    ok = ~(clipped | crushed)
    error = np.abs(photo.image[ok] - _expected(scene)[ok])
    assert error.max() < _tolerance(), (error.max(), _tolerance())
    assert photo.exif["exposure_time"] == pytest.approx(1 / 125, rel=1e-6) and photo.exif["iso"] == 200
    assert photo.exif["f_number"] == 4.0 and photo.exif["focal_length"] == 50.0
    assert photo.exif["focal_length_35mm"] == 75  # from the Exif IFD: LibRaw does not report it
    assert photo.relative_exposure == pytest.approx((1 / 125) * 200 / 16, rel=1e-6)

    write_dng(tmp_path / "turned.dng", sensels, orientation=6)  # the camera held upright: view it turned clockwise
    turned = read_photo(tmp_path / "turned.dng")
    assert np.array_equal(turned.image, np.rot90(photo.image, -1))
    assert np.array_equal(turned.clipped, np.rot90(clipped, -1)) and np.array_equal(
        turned.crushed, np.rot90(crushed, -1)
    )
    assert any("orientation" in note for note in turned.notes) and turned.exif == {}


def test_as_shot_white_balance_makes_a_grey_card_grey(tmp_path):
    """Under a warm light L the camera reads a grey card as D·M·L, its AsShotNeutral: the card comes back
    neutral (R = G = B, its reflectance times the neutral's smallest channel), while a white balance for the camera's
    daylight (D) would leave it the light's colour."""
    light = np.array([1.0, 0.8, 0.55])
    neutral = _camera(light)
    # A bright card (its green sensels at 77% of the range) and nothing clipped: were LibRaw left to guess the
    # white level from the data (its adjust_maximum_thr, 75%), it would take the card's green for it.
    card = np.broadcast_to(0.95 * light, (48, 64, 3))
    write_dng(tmp_path / "warm.dng", _mosaic(_camera(card)), neutral=neutral)
    photo = read_photo(tmp_path / "warm.dng")
    grey = 0.95 * neutral.min()  # the white balance's largest multiplier, 1/min(neutral), is 1 (module docstring)
    assert np.abs(photo.image - grey).max() < _tolerance()


def test_linear_raw_dng_is_read_at_full_size(tmp_path):
    """A LinearRaw DNG (demosaicked by the camera or a converter): full size, each pixel flagged by its own
    channels."""
    scene = RNG.uniform(0.05, 0.8, (32, 48, 3))
    sensels = np.round(BLACK + _camera(scene) * (WHITE - BLACK)).astype(np.uint16)
    sensels[3, 5, 2] = WHITE
    sensels[20, 7, 0] = BLACK
    write_dng(tmp_path / "linear.dng", sensels)
    photo = read_photo(tmp_path / "linear.dng")
    assert photo.image.shape == (32, 48, 3)
    assert np.argwhere(photo.clipped).tolist() == [[3, 5]] and np.argwhere(photo.crushed).tolist() == [[20, 7]]
    ok = ~(photo.clipped | photo.crushed)
    # No greens to average here, so half a code less; the bound above still holds.
    assert np.abs(photo.image[ok] - _expected(scene)[ok]).max() < _tolerance()


def test_raw_photos_make_a_target_whose_gains_exif_ties(tmp_path):
    """The shipped photo-like brown swatch with its two PNGs replaced by DNGs of the Cycles renders (each
    render pixel a 2×2 quad, half its hair's highlight over the white level): the target loads at the scenes'
    64×64, a gain per image and its white balance fitted (raw is exposed and balanced by a camera), its gains
    tied by EXIF where target.toml says gains = "exif", its clipped quads left out, and its other pixels the
    render times min(D)."""
    source = targets.path("photo_brown_straight_png")
    directory = tmp_path / "raw_target"
    shutil.copytree(source, directory)
    spec = directory / "target.toml"
    renders = {}
    for view, exposure in (("front", 1 / 60), ("back", 1 / 30)):
        render, _ = read_exr(targets.path("cycles_brown_straight") / f"{view}.exr")
        render = render * (1.0 / np.percentile(_camera(render), 99.5))  # a little of the highlight clips
        renders[view] = render
        sensels = _mosaic(_camera(np.repeat(np.repeat(render, 2, 0), 2, 1)).clip(0, 1))
        write_dng(directory / f"{view}.dng", sensels, exif=(exposure, 5.6, 100, 85.0, 85))
        (directory / f"{view}.png").unlink()
    spec.write_text(spec.read_text().replace(".png", ".dng"))
    assert (load_target(directory).gains, load_target(directory).white_balance) == ("per-image", "fit")
    spec.write_text('gains = "exif"\n' + spec.read_text().replace('gains = "per-image"\n', ""))
    target = load_target(directory)
    assert (target.gains, target.white_balance) == ("exif", "fit")
    for image in target.images:
        camera = _camera(renders[image.name])
        flagged = (camera >= 1).any(-1) | (camera <= 0.5 / (WHITE - BLACK)).any(-1)  # at white; rounded to black
        assert 0 < flagged.sum() and np.array_equal(~image.mask, flagged)
        error = np.abs(image.image - _expected(renders[image.name]))[image.mask]
        assert error.max() < _tolerance()
    assert target.images[1].photo.relative_exposure == pytest.approx(2 * target.images[0].photo.relative_exposure)


def test_bad_raw_files_are_clear_errors(tmp_path, monkeypatch):
    sensels = _mosaic(_camera(np.full((48, 64, 3), 0.3)))
    write_dng(tmp_path / "whole.dng", sensels)
    data = (tmp_path / "whole.dng").read_bytes()
    (tmp_path / "cut.dng").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut.dng: damaged or truncated raw file"):
        read_photo(tmp_path / "cut.dng")
    (tmp_path / "noise.nef").write_bytes(RNG.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"noise.nef: not a raw file LibRaw [\d.]+ reads.*convert it"):
        read_photo(tmp_path / "noise.nef")
    Image.new("RGB", (32, 32), (90, 60, 30)).save(tmp_path / "renamed.cr2", format="JPEG")
    with pytest.raises(ValueError, match=r"renamed.cr2: not camera raw .* but a JPEG image.*\(\.jpeg\)"):
        read_photo(tmp_path / "renamed.cr2")
    with pytest.raises(ValueError, match=r"whole.dng: camera raw holds linear sensor values; transfer = 'srgb'"):
        read_photo(tmp_path / "whole.dng", transfer="srgb")
    with pytest.raises(FileNotFoundError, match=r"absent\.arw: image not found"):
        read_photo(tmp_path / "absent.arw")
    monkeypatch.setitem(sys.modules, "rawpy", None)  # as where rawpy is not installed
    with pytest.raises(ValueError, match=r"whole.dng: camera raw needs rawpy .*warp-hair\[photo\]"):
        read_photo(tmp_path / "whole.dng")
