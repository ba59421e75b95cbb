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

Decisions on odd files (each an error naming the file, or a note in `Photo.notes`):
- JPEG, PNG and TIFF with 8 or 16 bits per channel (float TIFF too); RGB, RGBA (alpha ignored), or greyscale
  replicated to grey. A 16-bit greyscale TIFF or PNG is read like any greyscale image (a note says so). CMYK
  is an error (a print separation, not a camera's light), and so is a palette PNG (its colours were quantised
  to 256: no fit of colour can trust it). Truncated or damaged files are errors, never partial images.
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import ExifTags, Image, ImageCms, ImageOps, UnidentifiedImageError

from .raw import RAW_SUFFIXES, read_raw

TRANSFERS = ("auto", "srgb", "linear")
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
}


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
        """t · ISO / N² from EXIF: proportional to the code value a given radiance gives, so the ratio of two
        photos' is the ratio of their gains (None where a tag is missing)."""
        t, n, iso = (self.exif.get(key) for key in ("exposure_time", "f_number", "iso"))
        if not all(isinstance(v, float) and v > 0 for v in (t, n, iso)):
            return None
        return t * iso / (n * n)


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
    if suffix in (".tif", ".tiff"):
        codes, bits, icc, exif, notes, fmt = _read_tiff(path)
    else:
        codes, bits, icc, exif, notes, fmt, gamma = _read_pillow(path)
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


def _read_pillow(path: Path):
    """(codes (H, W, 3) uint8/uint16, bits, ICC bytes or None, exif, notes, format, PNG gamma or None)."""
    notes = []
    try:
        with Image.open(path) as im:
            fmt = im.format
            im.load()  # decode now: a truncated file fails here, not later
            exif = _exif(im.getexif())
            orientation = im.getexif().get(ExifTags.Base.Orientation, 1)
            if orientation not in (1, None):
                im = ImageOps.exif_transpose(im)
                notes.append(f"EXIF Orientation {orientation} applied (the image as a viewer shows it)")
            icc = im.info.get("icc_profile") or None
            gamma = im.info.get("gamma") if not (icc or "srgb" in im.info) else None
            mode = im.mode
            if mode == "P" or mode == "PA":
                raise ValueError(
                    f"{path}: a palette image (its colours quantised to a table of at most 256): "
                    "save the photo as RGB, not indexed colour"
                )
            if mode == "CMYK":
                raise ValueError(f"{path}: a CMYK image (print separations, not a camera's light): save it as RGB")
            if mode in ("RGB", "RGBA", "RGBX"):
                return np.asarray(im.convert("RGB")), 8, icc, exif, notes, fmt, gamma
            if mode in ("L", "LA", "1"):
                notes.append("greyscale: replicated to R = G = B")
                return np.repeat(np.asarray(im.convert("L"))[..., None], 3, -1), 8, icc, exif, notes, fmt, gamma
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                grey = np.asarray(im).astype(np.int64)
                if grey.max(initial=0) > 65535 or grey.min(initial=0) < 0:
                    raise ValueError(f"{path}: 32-bit integer pixels: save it as 8- or 16-bit")
                notes.append("16-bit greyscale: replicated to R = G = B")
                return np.repeat(grey.astype(np.uint16)[..., None], 3, -1), 16, icc, exif, notes, fmt, gamma
            raise ValueError(f"{path}: image mode {mode!r} is not read; save it as 8- or 16-bit RGB")
    except (UnidentifiedImageError, OSError, SyntaxError) as error:
        raise ValueError(
            f"{path}: damaged, truncated or unsupported {path.suffix.lstrip('.').upper()} file: {error}"
        ) from None


def _read_tiff(path: Path):
    """TIFF through tifffile (Pillow reads neither 16-bit RGB nor float TIFF): (codes, bits, icc, exif, notes, fmt)."""
    import tifffile

    notes = []
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            data = page.asarray()
            tags = page.tags
            icc = tags["InterColorProfile"].value if "InterColorProfile" in tags else None
            photometric = int(page.photometric)
            exif_tag = tags.get("ExifTag")
            raw_exif = exif_tag.value if exif_tag is not None else {}
    except Exception as error:  # tifffile raises TiffFileError, ValueError, struct.error, ... for damaged files
        raise ValueError(f"{path}: damaged, truncated or unsupported TIFF file: {error}") from None
    if photometric == 5:  # SEPARATED
        raise ValueError(f"{path}: a CMYK image (print separations, not a camera's light): save it as RGB")
    if photometric == 3:  # PALETTE
        raise ValueError(f"{path}: a palette image (its colours quantised to a table): save the photo as RGB")
    if data.ndim == 3 and data.shape[0] in (3, 4) and data.shape[-1] not in (3, 4):
        data = np.moveaxis(data, 0, -1)  # planar configuration
    if data.ndim == 2:
        notes.append(f"{data.dtype.itemsize * 8}-bit greyscale: replicated to R = G = B")
        data = np.repeat(data[..., None], 3, -1)
    if data.ndim != 3 or data.shape[-1] not in (3, 4):
        raise ValueError(f"{path}: pixels of shape {data.shape}; a photo is (height, width, RGB)")
    data = data[..., :3]
    if data.dtype == np.uint8:
        bits = 8
    elif data.dtype == np.uint16:
        bits = 16
    elif data.dtype.kind == "f":
        bits, data = 32, data.astype(np.float32)
        notes.append("floating-point TIFF: linear values, not clipped")
    else:
        raise ValueError(f"{path}: {data.dtype} pixels are not read; save it as 8- or 16-bit or float RGB")
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


def write_photo(path, linear, quality: int = 90) -> None:
    """Write linear RGB as a camera writes it: clipped at 1 (highlights beyond the range lost), sRGB-encoded,
    8 bits, as PNG or (by the suffix) JPEG at `quality`. The photo-like targets are made so
    (benchmarks/make_photo_targets.py)."""
    from .io import _replaced, _rgb_image, srgb_encode

    path = Path(path)
    image = _rgb_image(linear)
    if not np.isfinite(image).all():
        raise ValueError(f"{path}: the image has NaN or infinite values")
    codes = np.round(srgb_encode(image) * 255.0).astype(np.uint8)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"{path}: write_photo writes .png or .jpg")
    with _replaced(path) as partial:
        if suffix == ".png":
            Image.fromarray(codes, "RGB").save(partial, format="PNG")
        else:
            Image.fromarray(codes, "RGB").save(partial, format="JPEG", quality=int(quality))
