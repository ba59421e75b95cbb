"""Photographs in: PNG, JPEG, TIFF and camera raw decoded to linear RGB, with what the camera did to them.

    photo = read_photo("front.jpg")            # transfer="auto": the file's ICC profile, else sRGB
    photo.image                                # float32 (H, W, 3) linear, 1.0 = the top of the file's range
    photo.clipped, photo.crushed               # (H, W) bool: pixels a fit must leave out
    photo.exif                                 # exposure_time, f_number, iso, focal_length, ... where present

A camera's JPEG is not radiance: its code values went through a transfer function (sRGB's, or one an embedded
ICC profile describes), were scaled by an exposure and a white balance nobody recorded exactly, and stop at the
top of the range (clipped) and at zero (crushed). Decoding undoes the transfer function; the exposure and white
balance are left to the fit (`optimize/camera.py`), and the clipped and crushed pixels are marked so that the
loss leaves them out: their true value is anywhere beyond the code they show.

Transfer functions (`transfer`):

    auto     EXR is linear; a float TIFF is linear; otherwise the ICC profile where the file has one (an sRGB
             profile decodes as sRGB, a profile whose name says linear or gamma 1.0 as linear, any other is
             converted to sRGB by LittleCMS through Pillow's ImageCms first), a PNG gAMA chunk without one, and
             sRGB for everything else (IEC 61966-2-1: what an untagged display-referred file means)
    srgb     the sRGB curve, whatever the file says
    linear   the code values are proportional to light (a linear TIFF from a raw converter; camera raw is
             always linear, and "srgb" for it is an error)

Decisions on odd files (each an error naming the file, or a note in `Photo.notes`; what they mean for a
target, with figures: docs/fitting.md, "Which photos are read"):
- Read: JPEG, PNG and TIFF of 8 or 16 bits per channel, and float TIFF; RGB, or greyscale replicated to
  R = G = B with a note and a `PhotoWarning` (it holds no colour for a fit to find). A 16-bit PNG is read at
  full depth through pypng (Pillow keeps the top 8 bits of 16-bit colour), an 8-bit one through Pillow.
- Refused, each saying what it is and what is read (`ACCEPTED`): CMYK (a print separation, not a camera's
  light), palette images (colours quantised to a table: no fit of colour can trust them), bilevel and 2- or
  4-bit greyscale, inverted-grey (MINISWHITE) TIFF, and any pixel not fully opaque (an alpha channel below its
  top, or a PNG tRNS colour key that a pixel matches: what lies behind it is not in the photo). A fully opaque
  alpha channel is dropped with a note. A file whose header declares more than `MAX_PIXELS` is refused before
  anything is decoded (a decompression bomb, or a damaged header); there is no switch: downscale a real photo
  that large.
- Truncated or damaged files are errors, never partial images. Every PNG chunk's CRC is checked (Pillow skips
  the image data's). A JPEG is decoded by libjpeg-turbo through simplejpeg with strict=True: each of libjpeg's
  corrupt-data warnings is an error (Pillow's libjpeg output handler drops them, and patches the image over).
  JPEG has no checksum: a changed byte after which the entropy-coded data falls back in step is seen by no
  decoder, and decodes to a few wrong blocks.
- A JPEG's clipped pixels are those with a channel at or above CLIP_CODE_JPEG/255 of the range, its crushed
  ones at or below CRUSH_CODE_JPEG/255: its block compression rings around a clipped highlight or a black
  region and leaves codes just inside the range there. Lossless files clip and crush at their end codes exactly.
- EXIF Orientation is applied (as a viewer shows the photo), with a note.
- Camera raw (`RAW_SUFFIXES`: .dng, .cr2, .cr3, .nef, .arw, .raf, ...) is read through LibRaw (rawpy, the
  `photo` extra; warp_hair/raw.py has its decisions): linear sRGB at half the sensor's size, white-balanced as
  shot, no gamma and no auto-brightening; a pixel is clipped where a sensel of its 2×2 quad reached the white
  level before white balance, crushed where one is at or below the black level. EXIF from LibRaw, and from the
  file's Exif IFD for the tags LibRaw does not report. A raw photo is linear but `camera_exposed`: the fit
  solves its gain and white balance as for a JPEG. A file LibRaw cannot read (a camera newer than it, a
  damaged file, a JPEG with a raw suffix) is an error saying which, with `RAW_HINT`'s advice: convert it to a
  16-bit linear TIFF and set transfer = "linear".
"""

from __future__ import annotations

import io
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import ExifTags, Image, ImageCms, UnidentifiedImageError

from .raw import RAW_SUFFIXES, read_raw

TRANSFERS = ("auto", "srgb", "linear")
# The most pixels a file may declare: Pillow's decompression-bomb bound (twice its MAX_IMAGE_PIXELS, 179
# megapixels), above the 100-150 of the largest medium-format sensors. Checked on the header, before decoding.
MAX_PIXELS = 2 * Image.MAX_IMAGE_PIXELS
ACCEPTED = "warp-hair reads 8- or 16-bit RGB (or greyscale) PNG, JPEG and TIFF, and float TIFF"
OPAQUE = "save the photo without transparency"
ORIENTATIONS = range(1, 9)
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
# A JPEG code at or above this (of 255) counts as clipped: compression ringing leaves codes below 255 around a
# clipped highlight (measured on Pillow's JPEGs at quality 90: up to 4 codes below the top).
CLIP_CODE_JPEG = 250
# And at or below this, crushed: the same ringing leaves codes just above 0 around a black region (up to 3 on an
# 8×8 black patch at quality 90).
CRUSH_CODE_JPEG = 3
# EXIF tags read (Exif IFD), as Photo.exif keys.
EXIF_TAGS = {
    "ExposureTime": "exposure_time",
    "FNumber": "f_number",
    "ISOSpeedRatings": "iso",
    "FocalLength": "focal_length",
    "FocalLengthIn35mmFilm": "focal_length_35mm",
    "ExposureBiasValue": "exposure_bias",
    "ShutterSpeedValue": "shutter_speed_value",  # APEX Tv = -log2(t): the exact stop, where ExposureTime names it
    "ApertureValue": "aperture_value",  # APEX Av = 2 log2(N)
}
# How far (in stops) an APEX value may lie from the rounded value it stands beside and still be read in its place:
# a rounded name is within a sixth of a stop of its stop (1/60 s names 2^-6 s: 0.093 stop); farther, the tags
# disagree (an edited file) and the rounded value, which a person sees, is read.
APEX_TOLERANCE = 1 / 3


class PhotoWarning(UserWarning):
    """A photo that decodes but constrains less than a fit may assume (a greyscale one: no colour)."""


@dataclass
class Photo:
    path: Path
    image: np.ndarray  # float32 (H, W, 3) linear, 1.0 = the top of the file's code range
    clipped: np.ndarray  # (H, W) bool: a channel at the top of the range
    crushed: np.ndarray  # (H, W) bool: a channel at zero
    format: str  # "PNG", "JPEG", "TIFF", or "<SUFFIX> raw" ("DNG raw")
    bits: int  # per channel: 8, 16 (raw: LibRaw's 16-bit output), or 32 (float)
    transfer: str  # what was undone: "srgb", "linear", "gamma 2.2", "icc:<profile> → srgb"
    exif: dict = field(default_factory=dict)  # EXIF_TAGS' values found, as floats
    notes: list = field(default_factory=list)  # decisions taken on this file, for the fit's report
    raw: bool = False  # camera raw (warp_hair.raw): linear, but exposed and white-balanced by the camera

    @property
    def display_referred(self) -> bool:
        """Whether the file holds display values (anything not linear): its exposure and white balance are a
        camera's choices, not the scene's light."""
        return self.transfer != "linear"

    @property
    def camera_exposed(self) -> bool:
        """Whether a camera's exposure and white balance set the values' scale, so that a fit solves gains and
        a white balance: display-referred files and camera raw (linear, yet scaled by the shutter, aperture,
        ISO and as-shot white balance). A linear TIFF is taken at its word, as an EXR is."""
        return self.display_referred or self.raw

    @property
    def relative_exposure(self) -> float | None:
        """t · ISO / N² from this photo's EXIF (`relative_exposure`), or None."""
        return relative_exposure(self.exif)


def relative_exposure(exif: dict) -> float | None:
    """t · ISO / N² from EXIF values (Photo.exif's keys): proportional to the code value a given radiance gives,
    so the ratio of two photos' is the ratio of their gains (None where a tag is missing).

    ExposureTime and FNumber are the rounded names a camera shows (1/60 s, f/5.6) of the stops it sets (2^-6 s,
    2^2.5), up to 7% apart in the ratio of two photos; where the file also has the APEX ShutterSpeedValue and
    ApertureValue (what DSLRs and phones write), those exact stops are read instead."""
    t, n, iso = (exif.get(key) for key in ("exposure_time", "f_number", "iso"))
    if not all(isinstance(v, (int, float)) and v > 0 for v in (t, n, iso)):
        return None
    stops_t, stops_n2 = -math.log2(t), 2 * math.log2(n)
    tv, av = exif.get("shutter_speed_value"), exif.get("aperture_value")
    if isinstance(tv, (int, float)) and abs(tv - stops_t) <= APEX_TOLERANCE:
        stops_t = tv
    if isinstance(av, (int, float)) and abs(av - stops_n2) <= APEX_TOLERANCE:
        stops_n2 = av
    return 2.0 ** (-stops_t - stops_n2) * iso


def read_photo(path, transfer: str = "auto") -> Photo:
    """Decode a PNG, JPEG, TIFF or camera raw file to linear RGB (see the module docstring); errors name the
    file."""
    path = Path(path)
    if transfer not in TRANSFERS:
        raise ValueError(f"{path}: transfer = {transfer!r}; allowed: {list(TRANSFERS)}")
    suffix = path.suffix.lower()
    if suffix not in PHOTO_SUFFIXES + RAW_SUFFIXES:
        raise ValueError(
            f"{path}: not an image type warp-hair reads (EXR, {', '.join(PHOTO_SUFFIXES)}, or camera raw: "
            f"{', '.join(RAW_SUFFIXES)})"
        )
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image not found")
    if suffix in RAW_SUFFIXES:
        return _read_raw_photo(path, transfer)
    gamma = None
    if suffix in (".tif", ".tiff"):
        codes, bits, icc, exif, notes, fmt = _read_tiff(path)
    else:
        reader = _read_png if suffix == ".png" else _read_jpeg
        codes, bits, icc, exif, notes, fmt, gamma, orientation = reader(path)
        codes = _to_rgb(path, codes, float(2**bits - 1), codes.shape[-1] in (2, 4), notes)
        if orientation != 1:
            codes = _oriented(codes, orientation)
            notes.insert(0, f"EXIF Orientation {orientation} applied (the image as a viewer shows it)")
    top = 1.0 if bits == 32 else float(2**bits - 1)
    values = codes.astype(np.float64) / top
    lossy = fmt == "JPEG"
    clip_level = CLIP_CODE_JPEG / 255.0 if lossy else 1.0
    clipped = (values >= clip_level - 1e-9).any(axis=-1) if bits != 32 else np.zeros(values.shape[:2], bool)
    crush_level = CRUSH_CODE_JPEG / 255.0 if lossy else 0.0
    crushed = (values <= crush_level + 1e-9).any(axis=-1) if bits != 32 else np.zeros(values.shape[:2], bool)
    if transfer == "auto":
        if bits == 32:
            transfer = "linear"
        elif icc is not None:
            values, transfer = _from_icc(path, values, icc, bits, notes)
        elif fmt == "PNG" and gamma is not None and abs(gamma - 1 / 2.2) > 0.01 and abs(gamma - 0.45455) > 1e-3:
            transfer = "linear" if abs(gamma - 1.0) < 1e-3 else f"gamma {1 / gamma:.3g}"
        else:
            transfer = "srgb"
    elif icc is not None:
        notes.append(f"transfer = {transfer!r} given: the file's ICC profile ({_profile_name(icc)}) is not used")
    linear = _decode(values, transfer)
    if not np.isfinite(linear).all():
        raise ValueError(f"{path}: NaN or infinite values in the image")
    if (linear < 0).any():
        raise ValueError(f"{path}: negative values in the image; a photograph's values are >= 0")
    return Photo(path, linear.astype(np.float32), clipped, crushed, fmt, bits, transfer, exif, notes)


def _read_raw_photo(path: Path, transfer: str) -> Photo:
    """Camera raw (warp_hair.raw): linear by nature; EXIF from LibRaw, else from the file's Exif IFD where the
    raw file is a TIFF (DNG, NEF, CR2, ARW, ...), for the tags LibRaw does not report."""
    if transfer not in ("auto", "linear"):
        raise ValueError(f"{path}: camera raw holds linear sensor values; transfer = {transfer!r} does not apply")
    decoded = read_raw(path)
    exif = dict(decoded.exif)
    for key, value in _tiff_exif(path).items():
        exif.setdefault(key, value)  # LibRaw's reading first: it knows makers' notes the Exif IFD may lack
    image = decoded.image
    if not np.isfinite(image).all():
        raise ValueError(f"{path}: NaN or infinite values in the decoded raw image")
    fmt = f"{path.suffix.lstrip('.').upper()} raw"
    return Photo(
        path,
        image.astype(np.float32),
        decoded.clipped,
        decoded.crushed,
        fmt,
        16,
        "linear",
        exif,
        decoded.notes,
        raw=True,
    )


def _tiff_exif(path: Path) -> dict:
    """EXIF_TAGS from a TIFF-based file's Exif IFD (tifffile), or {} where it is not a TIFF or has none."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            exif_tag = tif.pages[0].tags.get("ExifTag")
            raw_exif = exif_tag.value if exif_tag is not None else {}
    except Exception:  # not a TIFF (CR3, RAF, ...), or a damaged Exif IFD: LibRaw's reading stands alone
        return {}
    return _exif_values(raw_exif)


def _exif_values(raw_exif: dict) -> dict:
    """EXIF_TAGS' values from tifffile's Exif IFD dictionary, as floats."""
    exif = {key: _number(raw_exif[tag]) for tag, key in EXIF_TAGS.items() if tag in raw_exif}
    return {k: v for k, v in exif.items() if v is not None}


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """The inverse of the sRGB transfer curve (IEC 61966-2-1), for values in [0, 1]."""
    x = np.asarray(encoded, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _decode(values: np.ndarray, transfer: str) -> np.ndarray:
    if transfer == "linear":
        return values
    if transfer.startswith("gamma "):
        return values ** float(transfer.split()[1])
    return srgb_decode(values)


def _too_large(path: Path, width: int, height: int) -> None:
    """An error where the file declares more than MAX_PIXELS: checked on the header, before anything is decoded."""
    if width * height > MAX_PIXELS:
        raise ValueError(
            f"{path}: the file declares a {width}x{height} image ({width * height / 1e6:.0f} megapixels), more "
            f"than warp-hair decodes ({MAX_PIXELS / 1e6:.0f} megapixels, MAX_PIXELS): a damaged or hostile header "
            "(a decompression bomb), or a photo larger than any camera's; if it is a real photo, downscale it "
            "first (a target is box-filtered to --resolution pixels across anyway)"
        )


def _metadata(path: Path, im, notes: list) -> tuple:
    """(ICC bytes or None, exif, EXIF orientation, PNG gamma or None) from an opened Pillow image."""
    exif_block = im.getexif()
    exif = _exif(exif_block)
    orientation = exif_block.get(ExifTags.Base.Orientation, 1)
    if orientation not in ORIENTATIONS:
        notes.append(f"EXIF Orientation {orientation!r} is not one of 1-8: ignored")
        orientation = 1
    icc = im.info.get("icc_profile") or None
    gamma = im.info.get("gamma") if not (icc or "srgb" in im.info) else None
    return icc, exif, orientation, gamma


def _read_jpeg(path: Path):
    """(codes (H, W, C) uint8, bits, ICC, exif, notes, format, None, orientation). The pixels are libjpeg-turbo's
    through simplejpeg with strict=True, which makes each of libjpeg's warnings (corrupt data that it would
    otherwise patch over: a bad Huffman code, a scan ending early or late, a bad marker) an error; Pillow drops
    them (its libjpeg output handler does nothing)."""
    import simplejpeg

    notes = []
    data = path.read_bytes()
    try:
        height, width, _, _ = simplejpeg.decode_jpeg_header(data)
    except ValueError as error:
        raise ValueError(f"{path}: damaged, truncated or not a JPEG file: {error}") from None
    _too_large(path, width, height)
    try:
        with Image.open(path, formats=("JPEG", "MPO")) as im:
            fmt, mode = "JPEG", im.mode
            icc, exif, orientation, _ = _metadata(path, im, notes)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, Image.DecompressionBombError) as error:
        raise ValueError(f"{path}: damaged, truncated or not a JPEG file: {error}") from None
    if mode == "CMYK":
        raise ValueError(f"{path}: a CMYK image (print separations, not a camera's light): save it as RGB")
    if mode not in ("RGB", "L"):
        raise ValueError(f"{path}: a JPEG in mode {mode!r}; {ACCEPTED}")
    try:
        codes = simplejpeg.decode_jpeg(data, colorspace="GRAY" if mode == "L" else "RGB", strict=True)
    except ValueError as error:
        raise ValueError(
            f'{path}: damaged or truncated JPEG (libjpeg: "{error}"): decoding it would make up the pixels '
            "it cannot read; copy the photo again from the camera or the original"
        ) from None
    return codes, 8, icc, exif, notes, fmt, None, orientation


def _read_png(path: Path):
    """(codes (H, W, C) uint8 or uint16, bits, ICC, exif, notes, format, gamma, orientation). Every chunk's CRC
    is checked (pypng; Pillow skips the image data's, and a flipped byte in it may still inflate), 16-bit
    samples are read at full depth through pypng (Pillow keeps only the top 8 bits of 16-bit colour), 8-bit ones
    through Pillow."""
    import png

    notes = []
    try:
        reader = png.Reader(filename=str(path))
        reader.preamble()
        width, height, bitdepth, colour_type = reader.width, reader.height, reader.bitdepth, reader.color_type
        key = getattr(reader, "transparent", None)
        for _ in reader.chunks():  # the CRCs of the rest
            pass
    except (png.Error, OSError, EOFError) as error:
        raise ValueError(f"{path}: damaged, truncated or not a PNG file: {error}") from None
    _too_large(path, width, height)
    if colour_type == 3:
        raise ValueError(
            f"{path}: a palette image (its colours quantised to a table of at most 256): save the photo as RGB, "
            "not indexed colour"
        )
    if bitdepth < 8:
        levels = "black and white" if bitdepth == 1 else f"{2**bitdepth} grey levels"
        raise ValueError(f"{path}: a {bitdepth}-bit greyscale PNG ({levels}), not a photograph's tones; {ACCEPTED}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # MAX_PIXELS is the bound
            with Image.open(path, formats=("PNG",)) as im:
                icc, exif, orientation, gamma = _metadata(path, im, notes)
                if bitdepth == 8:
                    im.load()  # decode now: a truncated file fails here, not later
                    codes = np.asarray(im)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, Image.DecompressionBombError) as error:
        raise ValueError(f"{path}: damaged, truncated or not a PNG file: {error}") from None
    if bitdepth == 16:
        try:
            _, _, rows, info = png.Reader(filename=str(path)).read()
            codes = np.array([np.frombuffer(row, np.uint16) for row in rows], np.uint16)
        except (png.Error, OSError, ValueError, EOFError) as error:
            raise ValueError(f"{path}: damaged or truncated PNG file: {error}") from None
        if codes.shape[:2] != (height, width * info["planes"]):
            raise ValueError(f"{path}: damaged or truncated PNG file: {len(codes)} of its {height} rows decode")
        codes = codes.reshape(height, width, info["planes"])
    if codes.ndim == 2:
        codes = codes[..., None]
    if key is not None:
        keyed = (codes == np.asarray(key, codes.dtype)).all(axis=-1)
        if keyed.any():
            raise ValueError(
                f"{path}: {int(keyed.sum())} of its {keyed.size} pixels are transparent (its tRNS colour key "
                f"{tuple(key)}): what lies behind them is not in the photo; {OPAQUE}"
            )
        notes.append(f"tRNS colour key {tuple(key)} matches no pixel: ignored")
    return codes, bitdepth, icc, exif, notes, "PNG", gamma, orientation


def _to_rgb(path: Path, codes: np.ndarray, top: float, alpha: bool, notes: list) -> np.ndarray:
    """(H, W, 3) from (H, W, C): an alpha channel (the last, where `alpha`) that is fully opaque dropped with a
    note, any other an error; greyscale replicated to R = G = B with a note and a PhotoWarning."""
    if alpha:
        opacity, codes = codes[..., -1], codes[..., :-1]
        seen_through = opacity < top
        if seen_through.any():
            raise ValueError(
                f"{path}: {int(seen_through.sum())} of its {seen_through.size} pixels are transparent or "
                f"translucent (alpha below {top:g}): what lies behind them is not in the photo; {OPAQUE}"
            )
        notes.append("alpha channel fully opaque: dropped")
    if codes.shape[-1] == 1:
        notes.append("greyscale: replicated to R = G = B; it holds no colour")
        warnings.warn(
            f"{path}: a greyscale photo, read as R = G = B: it holds no colour, so the hair's colour cannot be "
            "fitted from it; use a colour photo to fit colour",
            PhotoWarning,
            stacklevel=3,
        )
        codes = np.repeat(codes, 3, axis=-1)
    if codes.shape[-1] != 3:
        raise ValueError(f"{path}: {codes.shape[-1]} channels; {ACCEPTED}")
    return codes


def _oriented(a: np.ndarray, orientation: int) -> np.ndarray:
    """`a` (H, W, ...) as a viewer shows it under EXIF Orientation 1-8 (Pillow's ImageOps.exif_transpose)."""
    if orientation in (5, 6, 7, 8):
        a = np.swapaxes(a, 0, 1)  # transposed: 5 as is; 6, 7 and 8 then flipped
        orientation = {5: 1, 6: 2, 7: 3, 8: 4}[orientation]
    if orientation in (2, 3):
        a = a[:, ::-1]
    if orientation in (3, 4):
        a = a[::-1]
    return np.ascontiguousarray(a)


def _read_tiff(path: Path):
    """TIFF through tifffile (Pillow reads neither 16-bit RGB nor float TIFF): (codes, bits, icc, exif, notes, fmt)."""
    import tifffile

    notes = []
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            _too_large(path, int(page.imagewidth), int(page.imagelength))
            data = page.asarray()
            tags = page.tags
            icc = tags["InterColorProfile"].value if "InterColorProfile" in tags else None
            photometric = int(page.photometric)
            extra = tuple(page.extrasamples or ())
            exif_tag = tags.get("ExifTag")
            raw_exif = exif_tag.value if exif_tag is not None else {}
    except ValueError as error:
        if str(error).startswith(str(path)):
            raise
        raise ValueError(f"{path}: damaged, truncated or unsupported TIFF file: {error}") from None
    except Exception as error:  # tifffile raises TiffFileError, struct.error, ... for damaged files
        raise ValueError(f"{path}: damaged, truncated or unsupported TIFF file: {error}") from None
    if data.dtype == bool:
        raise ValueError(f"{path}: a 1-bit TIFF (black and white), not a photograph's tones; {ACCEPTED}")
    if photometric == 5:  # SEPARATED
        raise ValueError(f"{path}: a CMYK image (print separations, not a camera's light): save it as RGB")
    if photometric == 3:  # PALETTE
        raise ValueError(f"{path}: a palette image (its colours quantised to a table): save the photo as RGB")
    if photometric not in (1, 2):  # MINISBLACK, RGB
        name = tifffile.PHOTOMETRIC(photometric).name if photometric in set(tifffile.PHOTOMETRIC) else photometric
        raise ValueError(f"{path}: a TIFF of photometric interpretation {name}; {ACCEPTED}")
    if data.ndim == 3 and data.shape[0] in (2, 3, 4) and data.shape[-1] not in (2, 3, 4):
        data = np.moveaxis(data, 0, -1)  # planar configuration
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or data.shape[-1] > 4:
        raise ValueError(f"{path}: pixels of shape {data.shape}; {ACCEPTED}")
    if data.dtype == np.uint8:
        bits = 8
    elif data.dtype == np.uint16:
        bits = 16
    elif data.dtype.kind == "f":
        bits, data = 32, data.astype(np.float32)
        notes.append("floating-point TIFF: linear values, not clipped")
    else:
        raise ValueError(f"{path}: {data.dtype} pixels are not read; {ACCEPTED}")
    colour = 3 if photometric == 2 else 1
    if data.shape[-1] > colour:
        # The first extra sample: alpha where ExtraSamples says so (1 associated, 2 unassociated), else unknown.
        alpha = bool(extra) and extra[0] in (1, 2)
        if not alpha:
            notes.append(f"{data.shape[-1] - colour} extra channel(s) of no stated meaning: dropped")
        data = data[..., : colour + alpha]
    else:
        alpha = False
    data = _to_rgb(path, data, 1.0 if bits == 32 else float(2**bits - 1), alpha, notes)
    return data, bits, icc, _exif_values(raw_exif), notes, "TIFF"


def _exif(exif) -> dict:
    """EXIF_TAGS' values from Pillow's Exif (the Exif IFD, or the main one), as floats."""
    found = {}
    try:
        sub = exif.get_ifd(ExifTags.IFD.Exif)
    except Exception:  # a damaged Exif block is read as having none
        sub = {}
    for tag, key in EXIF_TAGS.items():
        number = getattr(ExifTags.Base, tag)
        value = sub.get(number, exif.get(number))
        value = _number(value)
        if value is not None:
            found[key] = value
    return found


def _number(value) -> float | None:
    """An EXIF value (a rational, a (num, den) pair, a tuple of ISOs) as a float, or None."""
    if isinstance(value, (tuple, list)):
        if len(value) == 2 and all(isinstance(v, int) for v in value) and value[1] != 0 and value[1] > 1:
            value = value[0] / value[1]
        elif value:
            value = value[0]
        else:
            return None
    try:
        value = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) else None


def _profile_name(icc: bytes) -> str:
    try:
        return ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(icc))).strip()
    except Exception:
        return "unreadable"


def _from_icc(path: Path, values: np.ndarray, icc: bytes, bits: int, notes: list) -> tuple:
    """(values, transfer): decoded as the profile says. sRGB profiles (by name) decode as sRGB and linear ones as
    linear; any other is converted to sRGB by ImageCms (LittleCMS) at 8 bits, which changes primaries too."""
    name = _profile_name(icc)
    lowered = name.lower()
    if "srgb" in lowered or "iec61966" in lowered.replace(" ", "").replace("-", ""):
        return values, "srgb"
    if "linear" in lowered or "gamma 1.0" in lowered or "g10" in lowered:
        return values, "linear"
    if name == "unreadable":
        raise ValueError(f'{path}: its embedded ICC profile cannot be read; set transfer = "srgb" or "linear"')
    if bits != 8:
        raise ValueError(
            f"{path}: a {bits}-bit image with the ICC profile {name!r}, which is neither sRGB nor "
            'linear: convert it to sRGB or linear in your editor, or set transfer = "srgb" or '
            '"linear" to say which it is'
        )
    source = ImageCms.ImageCmsProfile(io.BytesIO(icc))
    image = Image.fromarray(np.round(values * 255).astype(np.uint8), "RGB")
    try:
        converted = ImageCms.profileToProfile(image, source, ImageCms.createProfile("sRGB"), outputMode="RGB")
    except ImageCms.PyCMSError as error:
        raise ValueError(
            f'{path}: cannot convert from its ICC profile {name!r}: {error}; set transfer = "srgb" or "linear"'
        ) from None
    notes.append(f"converted from its ICC profile {name!r} to sRGB (LittleCMS, 8 bits)")
    return np.asarray(converted).astype(np.float64) / 255.0, f"icc:{name} → srgb"


def write_photo(path, linear, quality: int = 90, exif: dict | None = None) -> None:
    """Write linear RGB as a camera writes it: clipped at 1 (highlights beyond the range lost), sRGB-encoded,
    8 bits, as PNG or (by the suffix) JPEG at `quality`, with `exif` (EXIF_TAGS' names to numbers) in its Exif
    IFD. The photo-like targets are made so (benchmarks/make_photo_targets.py)."""
    from .io import _replaced, _rgb_image, srgb_encode

    path = Path(path)
    image = _rgb_image(linear)
    if not np.isfinite(image).all():
        raise ValueError(f"{path}: the image has NaN or infinite values")
    codes = np.round(srgb_encode(image) * 255.0).astype(np.uint8)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"{path}: write_photo writes .png or .jpg")
    extra = {"exif": _exif_bytes(path, exif)} if exif else {}
    with _replaced(path) as partial:
        if suffix == ".png":
            Image.fromarray(codes, "RGB").save(partial, format="PNG", **extra)
        else:
            Image.fromarray(codes, "RGB").save(partial, format="JPEG", quality=int(quality), **extra)


def _exif_bytes(path: Path, values: dict) -> bytes:
    """An Exif block holding `values` (EXIF_TAGS' names) in its Exif IFD: rationals, ISO as an integer."""
    from fractions import Fraction

    from PIL.TiffImagePlugin import IFDRational

    block = Image.Exif()
    ifd = block.get_ifd(ExifTags.IFD.Exif)
    for name, value in values.items():
        if name not in EXIF_TAGS:
            raise ValueError(f"{path}: EXIF tag {name!r} is not one warp-hair writes ({', '.join(EXIF_TAGS)})")
        number = getattr(ExifTags.Base, name)
        if name == "ISOSpeedRatings":
            ifd[number] = int(value)
        else:
            fraction = Fraction(float(value)).limit_denominator(100000)
            ifd[number] = IFDRational(fraction.numerator, fraction.denominator)
    return block.tobytes()  # Pillow writes a PNG's eXIf chunk from bytes only
