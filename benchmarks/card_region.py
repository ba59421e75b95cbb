"""What a grey card marked in a photo buys (optimize/card_region.py): `targets check` with and without one.

    python benchmarks/card_region.py                          # the three PNG photo-like targets, cards 8 and 16 px
    python benchmarks/card_region.py photo_brown_straight_png --sizes 8 16 32 --model-error 0

Each shipped PNG photo-like target (benchmarks/make_photo_targets.py) is checked as shipped, then with an 18%
grey card facing the camera pasted into a corner of its front view (tests/helpers/cards.py: the card's radiance
in the front light times the camera's true gains, sRGB-encoded into the PNG; it hides the hair behind it). The
back view is lit from behind the swatch, so a card the camera sees there gets no light: it has none. Printed per
case: the albedo's σ from the target's noise and expected (with the model error: 1% for these Cycles-rendered
targets unless --model-error), its shift per 1% brighter hair, and the gains' and white balance's σ. docs/fitting.md
("A grey card in the photo") quotes a run.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import targets
from optimize.identify import check_target
from optimize.target import load_target

HERE = Path(__file__).resolve().parent
DEFAULT = ("photo_blonde_straight_png", "photo_brown_straight_png", "photo_dark_wavy_png")


def _row(name: str, card: str, result) -> str:
    albedo = [k for k, label in enumerate(result.labels) if label.startswith("albedo")]
    noise = "/".join(f"{result.noise[k]:.4f}" for k in albedo)
    sigma = "/".join(f"{result.sigma[k]:.4f}" for k in albedo)
    shift = "/".join(f"{result.shift[k]:+.4f}" for k in albedo)
    camera = "  ".join(f"{label} {100 * s:.2f}%" for label, _, s in result.camera)
    return f"{name:<28} {card:<11} {noise:<22} {sigma:<22} {shift:<25} {camera}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*", default=list(DEFAULT), help="shipped PNG photo-like targets")
    parser.add_argument("--sizes", type=int, nargs="+", default=[8, 16], help="card squares' sides, in pixels")
    parser.add_argument("--model-error", type=float, default=None, help="as `targets check --model-error`")
    parser.add_argument(
        "--exif",
        action="store_true",
        help='also with EXIF exposures in the photos (a manual shoot\'s) and gains = "exif": one gain, its ratios '
        "EXIF's, so that the front view's card pins the back view's gain too",
    )
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(HERE.parent / "tests"))
    from helpers.cards import with_card

    print(
        f"{'target':<28} {'card':<11} {'albedo σ noise (r/g/b)':<22} {'albedo σ expected':<22} "
        f"{'shift per 1% brighter':<25} camera σ"
    )
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.names:
            for exif, size in [(False, s) for s in [0, *args.sizes]] + [
                (True, s) for s in [0, *args.sizes] if args.exif
            ]:
                begun = time.perf_counter()
                if size == 0 and not exif:
                    directory = targets.path(name)
                else:
                    directory = Path(scratch) / f"{name}_{size}_{exif}"
                    shutil.rmtree(directory, ignore_errors=True)
                    views = ("front",) if size else ()
                    with_card(targets.path(name), directory, views, box=(0, size, 0, size), exif=exif)
                result = check_target(load_target(directory), model_error=args.model_error, threads=args.threads)
                card = ("none" if size == 0 else f"{size}x{size}") + ("+exif" if exif else "")
                print(_row(name, card, result) + f"  ({time.perf_counter() - begun:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
