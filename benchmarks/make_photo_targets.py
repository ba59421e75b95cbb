"""Make the photo-like targets: the Cycles-rendered swatches as a camera would have saved them.

    python benchmarks/make_photo_targets.py                 # targets/photo_<name>_{png,jpeg}, shipped
    python benchmarks/make_photo_targets.py --exr DIR       # also the same exposures as linear EXR, under DIR

No photograph of a calibrated hair swatch can be downloaded here, so the photo-like targets are made from the
peer renders (`targets/cycles_*`: draped swatches of light, medium and dark hair whose fibers do not touch,
rendered by Blender Cycles): each view auto-exposed as a camera does (its 99.5th percentile brought to 0.9 of the
range, so the brightest highlights clip), a white balance off by up to 10% per channel (WHITE_BALANCE), then
clipped at the top of the range, sRGB-encoded and written at 8 bits as PNG and as JPEG at quality 90
(`warp_hair.photo.write_photo`). camera_truth.json records the gains and white balance applied, normalised as
the fit reports them (green's white balance 1, each view's gain on green). The `--exr` copies keep the same
exposures unclipped and linear, so that the fits' tables show what the camera costs (docs/acceptance.md).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

import numpy as np

import targets
from warp_hair.io import read_exr, write_exr
from warp_hair.photo import write_photo

# Light, medium and dark hair; each a white balance within ±10% per channel, as a camera's auto white balance
# misses a light's colour.
SOURCES = {
    "cycles_blonde_straight": (1.08, 1.0, 0.93),
    "cycles_brown_straight": (1.06, 1.0, 0.92),
    "cycles_dark_wavy": (0.94, 1.0, 1.07),
}
PERCENTILE, LEVEL = 99.5, 0.9
JPEG_QUALITY = 90
FORMATS = {"png": ".png", "jpeg": ".jpg"}


# The camera of the Blender swatches' photos (blender_swatch_acceptance.py), which records its exposure: aperture
# priority at f/8 and ISO 100, the shutter set on the third stop nearest what auto exposure asks for, and EXIF
# written as a camera writes it: ExposureTime the stop's rounded name (1/60 s for 2^-6 s), ShutterSpeedValue and
# ApertureValue its APEX values. A shutter of SHUTTER_AT_GAIN_1 gives the renders' radiance a gain of 1 (the
# scale is arbitrary: a fit reads only the views' ratios).
F_NUMBER, ISO = 8.0, 100
SHUTTER_AT_GAIN_1 = 2.0**-7
# The third-stop shutter speeds' names, from 2^5 s (30 s) down to 2^-13 s (1/8000 s).
SHUTTER_NAMES = (
    [30, 25, 20, 15, 13, 10, 8, 6, 5, 4, 3.2, 2.5, 2, 1.6, 1.3, 1, 0.8, 0.6, 0.5, 0.4, 0.3]
    + [1 / d for d in (4, 5, 6, 8, 10, 13, 15, 20, 25, 30, 40, 50, 60, 80, 100, 125, 160, 200, 250, 320, 400)]
    + [1 / d for d in (500, 640, 800, 1000, 1250, 1600, 2000, 2500, 3200, 4000, 5000, 6400, 8000)]
)
LONGEST_THIRD = 15  # SHUTTER_NAMES[0] names 2^(15/3) s


def auto_exposure(image: np.ndarray) -> float:
    """A camera's auto exposure, roughly: the gain that brings the 99.5th percentile of the image to 0.9."""
    return LEVEL / float(np.percentile(image, PERCENTILE))


def camera_exposure(image: np.ndarray) -> tuple[float, dict]:
    """(gain, EXIF) of the recording camera above: the gain auto exposure asks for, set on the nearest third
    stop of shutter time."""
    third = round(3 * math.log2(auto_exposure(image) * SHUTTER_AT_GAIN_1))
    index = LONGEST_THIRD - third
    if not 0 <= index < len(SHUTTER_NAMES):
        raise ValueError(f"the exposure asks for a shutter of 2^({third}/3) s, beyond 30 s to 1/8000 s")
    seconds = 2.0 ** (third / 3)
    exif = {
        "ExposureTime": SHUTTER_NAMES[index],
        "ShutterSpeedValue": -third / 3,
        "FNumber": F_NUMBER,
        "ApertureValue": 2 * math.log2(F_NUMBER),
        "ISOSpeedRatings": ISO,
    }
    return seconds / SHUTTER_AT_GAIN_1, exif


def make(name: str, out_root: Path, kind: str) -> Path:
    """targets/photo_<name>_<kind> (kind png, jpeg, exr) from the shipped target `name`; returns the directory."""
    source = targets.path(name)
    white_balance = np.array(SOURCES[name])
    directory = out_root / f"photo_{name.removeprefix('cycles_')}_{kind}"
    directory.mkdir(parents=True, exist_ok=True)
    lines = [
        f"# {name} as a camera saves it (benchmarks/make_photo_targets.py): auto-exposed views, white balance "
        f"{tuple(white_balance)}, "
        + ("linear EXR, unclipped." if kind == "exr" else f"clipped, sRGB, 8-bit {kind.upper()}."),
        'renderer = "cycles"',
    ]
    if kind == "exr":
        lines += ['gains = "per-image"', 'white_balance = "fit"']  # linear files default to none
    gains = {}
    for view in ("front", "back"):
        image, _ = read_exr(source / f"{view}.exr")
        exposure = auto_exposure(image)
        exposed = image * np.float32(exposure) * white_balance.astype(np.float32)
        file = f"{view}{'.exr' if kind == 'exr' else FORMATS[kind]}"
        if kind == "exr":
            write_exr(directory / file, exposed)
        else:
            write_photo(directory / file, exposed, quality=JPEG_QUALITY)
        shutil.copy(source / f"scene_{view}.toml", directory / f"scene_{view}.toml")
        gains[view] = exposure * white_balance[1]
        lines += ["", "[[images]]", f'scene = "scene_{view}.toml"', f'image = "{file}"']
    (directory / "target.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    shutil.copy(source / "truth.json", directory / "truth.json")
    truth = {"gains": gains, "white_balance": (white_balance / white_balance[1]).tolist()}
    (directory / "camera_truth.json").write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    return directory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--exr", type=Path, metavar="DIR", help="also write the linear EXR copies under DIR")
    parser.add_argument("names", nargs="*", default=list(SOURCES), help="of SOURCES (default all)")
    args = parser.parse_args()
    for name in args.names:
        for kind in FORMATS:
            print(make(name, targets.root(), kind))
        if args.exr:
            print(make(name, args.exr, "exr"))


if __name__ == "__main__":
    main()
