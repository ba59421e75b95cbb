"""Images in and out: linear RGB as OpenEXR (with metadata saying how it was made), and tone-mapped PNG.

Images are float32 (H, W, 3) arrays of linear RGB radiance, row 0 at the top.
"""

from __future__ import annotations

import contextlib
import json
import os
import tomllib
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from . import validate

# Every EXR file starts with these four bytes (0x762f3101, little-endian).
EXR_MAGIC = b"\x76\x2f\x31\x01"
# Header attributes the OpenEXR library writes or interprets itself; metadata must not overwrite them.
RESERVED_ATTRIBUTES = frozenset(
    {
        "channels",
        "chunkCount",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
        "name",
        "pixelAspectRatio",
        "screenWindowCenter",
        "screenWindowWidth",
        "tiles",
        "type",
        "version",
    }
)


def write_exr(path, image, metadata=None):
    """Write `image` as a 32-bit float R, G, B EXR with ZIP compression.

    Each `metadata` key becomes a header attribute holding its value as a JSON string (so `read_exr` gives the
    same values back), e.g. {"warp_hair": {"scene": ..., "spp": 64, "seed": 0}}.
    """
    path = Path(path)
    image = _rgb_image(image)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(_metadata_attributes(metadata or {}))
    channels = {name: np.ascontiguousarray(image[..., c]) for c, name in enumerate("RGB")}
    with _replaced(path) as partial:
        try:
            with OpenEXR.File(header, channels) as exr:
                exr.write(str(partial))
        except RuntimeError as error:
            raise OSError(f"{path}: cannot write the EXR file: {error}") from None


@contextlib.contextmanager
def _replaced(path):
    """A temporary name beside `path` to write to, renamed onto `path` once complete: an interrupted or failed
    write leaves no partial file (and an existing file untouched)."""
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        yield partial
        os.replace(partial, path)
    except BaseException:
        with contextlib.suppress(OSError):
            partial.unlink()
        raise


def _rgb_image(image):
    image = np.asarray(image, dtype=np.float32)
    if image.ndim != 3 or image.shape[2] != 3 or 0 in image.shape:
        raise ValueError(f"an image must have shape (H, W, 3) with H, W ≥ 1, got {image.shape}")
    return image


def _metadata_attributes(metadata):
    attributes = {}
    for key, value in metadata.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty strings, got {key!r}")
        if key in RESERVED_ATTRIBUTES:
            raise ValueError(f"metadata key {key!r} is a standard EXR attribute; choose another name")
        try:
            attributes[key] = json.dumps(value)
        except TypeError as error:
            raise ValueError(f"metadata {key!r} cannot be written as JSON: {error}") from None
    return attributes


def read_exr(path):
    """(image float32 (H, W, 3), metadata dict) from an EXR file.

    Takes R, G, B (half or float; A and other channels are ignored), or a lone Y channel, replicated to grey.
    Metadata holds every string attribute of the header, JSON-decoded where it is JSON (as `write_exr` writes
    it), else as the raw string.
    """
    path = Path(path)
    channels, header = _read_channels(path)
    if all(name in channels for name in "RGB"):
        planes = [channels[name] for name in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise ValueError(f"{path}: no R, G, B or Y channels to read; the file has {sorted(channels)}")
    image = np.stack(planes, axis=-1).astype(np.float32)
    metadata = {key: _decoded(value) for key, value in header.items() if isinstance(value, str)}
    return image, metadata


def _read_channels(path):
    """({channel name: pixels (H, W)}, header), with the library's errors turned into messages naming the file."""
    try:
        with open(path, "rb") as f:
            magic = f.read(len(EXR_MAGIC))
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such EXR file") from None
    except OSError as error:
        raise ValueError(f"{path}: cannot read the file: {error}") from None
    if magic != EXR_MAGIC:
        raise ValueError(f"{path}: not an EXR file (it does not start with the EXR magic number)")
    try:
        exr = OpenEXR.File(str(path), separate_channels=True)
        # A damaged file may open and fail only here, when its (missing) parts are asked for.
        return {name: channel.pixels for name, channel in exr.channels().items()}, exr.header()
    except Exception as error:  # the bindings raise RuntimeError, IndexError, ... for damaged files
        raise ValueError(f"{path}: damaged or unsupported EXR file: {error}") from None


def _decoded(text):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def read_text(path: Path, what: str, hint: str = "") -> str:
    """A UTF-8 text file's contents; a missing file is FileNotFoundError "<path>: <what> not found<hint>", an
    unreadable one ValueError "<path>: cannot read the <what>: <reason>"."""
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: {what} not found{hint}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: cannot read the {what}: {error}") from None


def read_toml(path: Path, what: str, hint: str = "") -> dict:
    """A TOML file's tables, with `read_text`'s errors and a ValueError "<path>: TOML syntax error: <where>"."""
    text = read_text(path, what, hint)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{path}: TOML syntax error: {error}") from None


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear values clipped to [0, 1], sRGB-encoded (the IEC 61966-2-1 transfer curve): what a display shows."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def write_png(path, image, exposure=1.0):
    """Write linear radiance as an 8-bit sRGB PNG for people to look at: image × exposure, clipped to [0, 1],
    sRGB-encoded. NaNs show black, +inf white. `exposure` must be a finite number > 0."""
    image = _rgb_image(image)
    exposure = validate.real("exposure", exposure)
    if not exposure > 0:
        raise ValueError(f"exposure must be > 0, got {exposure!r}")
    encoded = srgb_encode(np.nan_to_num(image * np.float32(exposure), nan=0.0))
    pixels = np.round(encoded * 255.0).astype(np.uint8)
    path = Path(path)
    with _replaced(path) as partial:
        try:
            Image.fromarray(pixels, mode="RGB").save(partial, format="PNG")
        except ValueError as error:
            raise OSError(f"{path}: cannot write the PNG file: {error}") from None
