"""Camera raw through LibRaw (rawpy): the sensor's linear values, white-balanced as shot, in linear sRGB.

    decoded = read_raw("shot.dng")     # warp_hair.photo.read_photo calls this for RAW_SUFFIXES
    decoded.image                      # float64 (H/2, W/2, 3): no gamma, no auto-brightening
    decoded.clipped, decoded.crushed   # (H/2, W/2) bool, as Photo's

Decisions (each one a parameter of LibRaw's processing, `PROCESSING`):
- Half size: each 2×2 Bayer quad becomes one pixel from its own four sensels (greens averaged), with no
  demosaicking. A photo target is box-filtered far below even half a sensor's width (`warp-hair targets photo
  --resolution`, optimize/photo_target.py), so interpolated detail would be averaged away; what half size
  gives instead is values free of a demosaic's guesses, a quarter of the memory, and a clipped pixel known
  exactly from its own sensels. A LinearRaw DNG (already demosaicked) is read at full size.
- White balance as shot (the camera's multipliers, a DNG's AsShotNeutral; daylight where the file has none,
  with a note). The fit solves a white balance anyway, but as a diagonal gain on sRGB: the camera's colour
  matrix to sRGB is defined on white-balanced camera values, and a diagonal applied after a matrix does not
  undo a diagonal missing before it. As shot leaves the fit a small residual to solve, not a wrong matrix.
- Black level subtracted and the white level scaled by LibRaw, from the file (LibRaw's guess that the
  saturation lies at the data's maximum, `adjust_maximum_thr`, is off: it rescales by the picture's content).
  The white balance's largest multiplier maps the white level to 1.0, so no channel is clipped by the white
  balance (highlight mode "ignore"); 16-bit output.
- Clipped: any sensel of the pixel's quad at its channel's white level (before white balance), or an output
  channel at the top of the 16-bit range (the colour matrix pushed it over). Crushed: any sensel at or below
  its black level, or an output channel at 0 (the matrix pushed it below, or the sensor read black).
  For other mosaics (X-Trans's 6×6), LibRaw's half size borrows from the neighbouring quads, so a pixel is
  flagged where its quad or a neighbour holds such a sensel.
- The file's orientation is applied to the image and its flags together, with a note.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

RAW_SUFFIXES = (
    ".dng",
    ".cr2",
    ".cr3",
    ".crw",
    ".nef",
    ".nrw",
    ".arw",
    ".srf",
    ".sr2",
    ".raf",
    ".orf",
    ".rw2",
    ".rwl",
    ".pef",
    ".srw",
    ".3fr",
    ".fff",
    ".iiq",
    ".mos",
    ".mrw",
    ".x3f",
    ".erf",
    ".kdc",
    ".dcr",
)
RAW_HINT = (
    "convert it with your raw converter to a 16-bit TIFF with a linear transfer curve (dcraw -4 -T, "
    "RawTherapee or darktable with a linear output profile; white balance as shot) and list that with "
    'transfer = "linear"'
)
# 16-bit output: the top and bottom codes are where LibRaw's colour conversion clipped.
TOP_CODE = 65535


def _processing(rawpy) -> dict:
    """LibRaw's postprocessing parameters (the module docstring's decisions)."""
    return {
        "half_size": True,
        "use_camera_wb": True,
        "output_color": rawpy.ColorSpace.sRGB,
        "gamma": (1.0, 1.0),
        "no_auto_bright": True,
        "adjust_maximum_thr": 0.0,
        "highlight_mode": rawpy.HighlightMode.Ignore,
        "output_bps": 16,
        "user_flip": 0,  # applied here, to the image and its flags together
    }


@dataclass
class RawDecoded:
    image: np.ndarray  # float64 (H, W, 3) linear sRGB, the white level at most 1.0
    clipped: np.ndarray  # (H, W) bool
    crushed: np.ndarray  # (H, W) bool
    exif: dict  # LibRaw's exposure_time, f_number, iso, focal_length where it found them (> 0)
    notes: list = field(default_factory=list)


def read_raw(path) -> RawDecoded:
    """Decode a camera raw file (see the module docstring); errors name the file."""
    path = Path(path)
    try:
        import rawpy
    except ImportError:
        raise ValueError(
            f"{path}: camera raw needs rawpy (LibRaw): pip install 'warp-hair[photo]'; or {RAW_HINT}"
        ) from None
    notes = []
    try:
        with rawpy.imread(str(path)) as raw:
            # The sensor's data first: postprocessing at half size halves LibRaw's sizes, and with them the
            # visible raw image it reports.
            sensels = np.array(raw.raw_image_visible)
            colours = None if raw.raw_type != rawpy.RawType.Flat else np.array(raw.raw_colors_visible)
            pattern = None if raw.raw_pattern is None else np.asarray(raw.raw_pattern)
            black = np.asarray(raw.black_level_per_channel, dtype=np.float64)
            white = np.full(4, float(raw.white_level))
            if raw.camera_white_level_per_channel is not None:  # the file's own levels, per channel
                own = np.asarray(raw.camera_white_level_per_channel, dtype=np.float64)
                white = np.where(own > 0, own, white)
            as_shot = list(raw.camera_whitebalance)
            flip = int(raw.sizes.flip)
            other = raw.other
            codes = raw.postprocess(**_processing(rawpy))
    except rawpy.LibRawFileUnsupportedError:
        raise ValueError(_unsupported(path, rawpy)) from None
    except (rawpy.LibRawIOError, rawpy.LibRawDataError) as error:
        raise ValueError(f"{path}: damaged or truncated raw file (LibRaw: {_message(error)})") from None
    except rawpy.LibRawError as error:
        raise ValueError(f"{path}: LibRaw cannot decode this raw file ({_message(error)}); {RAW_HINT}") from None
    if not any(as_shot[:3]):
        notes.append("no as-shot white balance in the file: LibRaw's daylight balance for the camera")
    if codes.ndim != 3 or codes.shape[-1] != 3 or not _matches(sensels.shape[:2], codes.shape[:2]):
        raise ValueError(
            f"{path}: LibRaw gave a {codes.shape} image from a {sensels.shape} sensor, neither its size nor half; "
            f"warp-hair cannot tell which pixels are clipped; {RAW_HINT}"
        )
    image = codes.astype(np.float64) / TOP_CODE
    at_white, at_black = _sensor_flags(sensels, colours, black, white)
    clipped = _to_output(at_white, codes.shape[:2], pattern) | (codes >= TOP_CODE).any(axis=-1)
    crushed = _to_output(at_black, codes.shape[:2], pattern) | (codes == 0).any(axis=-1)
    if flip:
        image, clipped, crushed = (_orient(a, flip) for a in (image, clipped, crushed))
        notes.append(f"the file's orientation (LibRaw flip {flip}) applied (the image as a viewer shows it)")
    if pattern is not None:
        notes.append("half size: each 2×2 sensor quad is one pixel (no demosaicking)")
    exif = {
        "exposure_time": float(other.shutter_speed),
        "f_number": float(other.aperture),
        "iso": float(other.iso_speed),
        "focal_length": float(other.focal_length),
    }
    exif = {key: value for key, value in exif.items() if np.isfinite(value) and value > 0}
    return RawDecoded(image, clipped, crushed, exif, notes)


def _message(error) -> str:
    text = error.args[0] if error.args else str(error)
    return text.decode(errors="replace") if isinstance(text, bytes) else str(text)


def _unsupported(path: Path, rawpy) -> str:
    """LibRaw refused the file: say what it is if Pillow knows it (an image with a raw suffix), else a raw
    format this LibRaw does not read."""
    from PIL import Image, UnidentifiedImageError

    version = ".".join(str(v) for v in rawpy.libraw_version)
    try:
        with Image.open(path) as im:
            kind = im.format
    except (UnidentifiedImageError, OSError):
        kind = None
    if kind is not None:
        return (
            f"{path}: not camera raw that LibRaw {version} reads but a {kind} image; if it is one, give it "
            f"its own suffix (.{kind.lower()}) to read it as such; if it is raw, {RAW_HINT}"
        )
    return f"{path}: not a raw file LibRaw {version} reads (an unknown camera, or not camera raw); {RAW_HINT}"


def _sensor_flags(sensels, colours, black, white) -> tuple:
    """(at white level, at or below black level) per sensel, (H, W): a mosaic's sensels by their colour, a
    stacked image's (LinearRaw) by any of its channels. Compared colour by colour in the sensels' own integers:
    a 24-megapixel mosaic would take 200 MB as float64."""
    if sensels.ndim == 2:
        if colours is None:
            return sensels >= white[0], sensels <= black[0]
        at_white, at_black = np.zeros(sensels.shape, bool), np.zeros(sensels.shape, bool)
        for c in np.unique(colours):
            mine = colours == c
            at_white |= mine & (sensels >= white[c])
            at_black |= mine & (sensels <= black[c])
        return at_white, at_black
    channels = range(min(sensels.shape[-1], 3))
    return (
        np.logical_or.reduce([sensels[..., c] >= white[c] for c in channels]),
        np.logical_or.reduce([sensels[..., c] <= black[c] for c in channels]),
    )


def _matches(sensor: tuple, output: tuple) -> bool:
    """Whether the output is the sensor's size or half of it (rounded up)."""
    return sensor == output or all(2 * o - 1 <= s <= 2 * o for s, o in zip(sensor, output))


def _to_output(flags: np.ndarray, shape: tuple, pattern) -> np.ndarray:
    """Sensel flags to output pixels (before orientation): a quad's any at half size (padded where the sensor
    has an odd row or column, as LibRaw rounds up), grown by a quad for mosaics other than 2×2."""
    height, width = shape
    if flags.shape == (height, width):
        return flags
    padded = np.zeros((2 * height, 2 * width), bool)
    rows, cols = min(flags.shape[0], 2 * height), min(flags.shape[1], 2 * width)
    padded[:rows, :cols] = flags[:rows, :cols]
    quads = padded.reshape(height, 2, width, 2).any(axis=(1, 3))
    if pattern is not None and pattern.shape != (2, 2):
        grown = np.pad(quads, 1)
        quads = np.zeros_like(quads)
        for dy in range(3):
            for dx in range(3):
                quads |= grown[dy : dy + height, dx : dx + width]
    return quads


def _orient(array: np.ndarray, flip: int) -> np.ndarray:
    """LibRaw's flip code applied as it applies it (dcraw's flip_index): mirror rows (2), mirror columns (1),
    then transpose (4); 3 is 180°, 5 a quarter turn anticlockwise, 6 clockwise."""
    if flip & 2:
        array = array[::-1]
    if flip & 1:
        array = array[:, ::-1]
    if flip & 4:
        array = array.swapaxes(0, 1)
    return np.ascontiguousarray(array)
