"""Fit targets: a directory of reference images, each with the scene file that describes how it was made.

    my_target/
        target.toml          # lists the images
        scene_front.toml     # camera, lights, fibers, [hair] (controls not fitted are taken from here)
        front.exr            # linear radiance, the size of the scene's camera
        scene_back.toml
        back.exr
        truth.json           # optional: the true controls, for reporting errors

target.toml:

    [[images]]
    scene = "scene_front.toml"
    image = "front.exr"
    mask = "front_mask.png"    # optional: white (or > 0.5 in an EXR's first channel) = pixels that count

    [[images]]
    scene = "scene_back.toml"
    image = "back.exr"

Photographs: an image may be a PNG, JPEG or TIFF (8 or 16 bit, or float) besides EXR (`warp_hair.photo`): it
is decoded to linear through its transfer function (per image, `transfer = "auto"` by default: the file's ICC
profile, else sRGB; or "srgb", "linear"), and its clipped and crushed pixels are left out of the loss (taken out
of the mask). A camera chose each photo's exposure and white balance, so they are fitted with the hair
(optimize/camera.py), as target.toml says:

    gains = "per-image"        # or "exif" (one gain, EXIF's t·ISO/N² ratios), "shared", "none"
    white_balance = "fit"      # or "none"

By default both are fitted when any image is display-referred (a gain per image: "exif" ties them only where one
lamp, as strong in every view, lit them, which the photographer says) and neither for linear images (EXR);
`warp-hair fit --gains/--white-balance` override.
A grey card in the shot that no scene models is marked per image and described once (optimize/card_region.py):

    [card]
    reflectance = 0.18                 # or [r, g, b], each in (0, 1]
    normal = "camera"                  # or [x, y, z] in scene coordinates

    [[images]]
    ...
    card_mask = "front_card.png"       # white = the card; its pixels are left out of the hair's
    card = {normal = [0, 0.3, 1]}      # optional: this image's card differs from [card] in these keys

Its pixels pin the gains and white balance (which a card makes unknowns even in an EXR target).

All images of a target show the same fibers with the same hair: their scenes' [fibers] and [hair] must agree.
`make_target` renders the images from their scenes (at the spp and seed of each scene's [render] table) and
writes truth.json from the [hair] table: what the shipped targets are made with (`warp-hair targets make`).
The shipped targets are the `targets` package's data; an installed package's copy is not rewritten (make_target
says so): remake them in a source checkout, or copy one elsewhere and make the copy.

A target rendered by another renderer says so in target.toml, `renderer = "cycles"` or `"mitsuba"` (default
"warp-hair"): its scene files describe for warp-hair what that renderer rendered, and `make_target` leaves its
images alone (`python benchmarks/make_peer_targets.py NAME` re-renders them, with that renderer installed).
A target that says nothing of its renderer, but whose images lack warp-hair's render record in their EXR headers
(what `make_target` and `warp-hair render` write), is of unknown origin (`Target.origin`): a photograph, or an
image from elsewhere. The fit assumes a brightness disagreement with such targets (`uncertainty.py`).

Where the scenes' fibers are a recipe (a [fibers] generator) rather than the very strands the images show (a
photographed swatch's never are), target.toml says

    realisations = "random"    # default "fixed": render the scenes' own strands

and the fit renders other realisations of the recipe and counts the target's being one of them in its
uncertainty (optimize/realisations.py; `warp-hair fit --realisations` overrides). How those strands lie, where
the recipe cannot say (jitter, layer gap, layers, how waves share their phase), may be stated as a prior the fit
averages over and estimates at its end (optimize/arrangement.py):

    [arrangement]
    jitter = [0.05, 0.4]
    layer_gap = [0.008, 0.015]
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import targets as shipped
from warp_hair.geometry.interpenetration import checked_interpenetration
from warp_hair.io import read_exr, write_exr
from warp_hair.model.params import HairParams
from warp_hair.photo import TRANSFERS, Photo, read_photo, relative_exposure
from warp_hair.realisation import check_realisable
from warp_hair.renderer.render import render, render_metadata
from warp_hair.scene import Scene, load_scene

from . import card_region
from .arrangement import Arrangement
from .arrangement import parse as arrangement_prior
from .camera import GAIN_MODES, WHITE_BALANCE_MODES
from .latents import EXPOSURE, SPECS
from .realisations import REALISATION_MODES

TARGET_FILE = shipped.TARGET_FILE
TRUTH_FILE = "truth.json"
IMAGE_KEYS = {"scene", "image", "mask", "transfer", "card_mask", "card"}
SPEC_KEYS = {"images", "renderer", "gains", "white_balance", "realisations", "card", "arrangement"}
# Who rendered a target's images: warp-hair itself, or a peer renderer (benchmarks/make_peer_targets.py).
RENDERERS = ("warp-hair", "mitsuba", "cycles")
# The shipped targets: the `targets` package's data, in a source checkout or an installed package.
SHIPPED_TARGETS = shipped.root()


@dataclass
class TargetImage:
    name: str  # the image file's stem, e.g. "front"
    scene: Scene
    image: np.ndarray  # (H, W, 3) float32 linear radiance
    mask: np.ndarray | None  # (H, W) bool, True where the pixel counts
    image_path: Path
    metadata: dict = field(default_factory=dict)  # the EXR header's string attributes (`warp_hair.io.read_exr`)
    photo: Photo | None = None  # a PNG, JPEG or TIFF's decoding: transfer, clipped and crushed pixels, EXIF
    card: card_region.CardRegion | None = None  # a grey card marked in the image (optimize/card_region.py)

    @property
    def photo_record(self) -> dict | None:
        """For an EXR `targets photo` decoded from a photo, its header's record of that photo (file, transfer,
        EXIF, bits, photo pixels per block); None otherwise."""
        record = self.metadata.get("photo")
        return record if isinstance(record, dict) else None

    @property
    def from_photo(self) -> bool:
        """Whether a camera made the image: a photo decoded here, or an EXR `targets photo` wrote from one."""
        return self.photo is not None or self.photo_record is not None

    @property
    def coding(self) -> tuple | None:
        """(bits, transfer, photo pixels averaged into each pixel) of the codes the camera wrote, for their
        rounding's variance (optimize/goodness.py): a photo's, or the record an EXR `targets photo` wrote keeps
        (targets made before it kept bits: None, as for a render)."""
        if self.photo is not None:
            return self.photo.bits, self.photo.transfer, 1.0
        record = self.photo_record
        if record is None or "bits" not in record:
            return None
        return int(record["bits"]), str(record.get("transfer", "srgb")), float(record.get("block", 1.0)) ** 2

    @property
    def relative_exposure(self) -> float | None:
        """EXIF's t·ISO/N² (warp_hair.photo.relative_exposure): the photo's, or, for an EXR `targets photo`
        decoded from one, the photo's EXIF its header keeps; None without."""
        if self.photo is not None:
            return self.photo.relative_exposure
        exif = (self.photo_record or {}).get("exif")
        return relative_exposure(exif) if isinstance(exif, dict) else None


@dataclass
class Target:
    name: str
    directory: Path
    images: list
    truth: HairParams | None
    renderer: str = "warp-hair"
    gains: str = "none"  # the images' exposures the fit solves for (optimize/camera.py): per-image, exif, shared
    white_balance: str = "none"  # "fit": a gain per channel, green's pinned
    realisations: str = "fixed"  # "random": the scenes' fibers are a recipe; fit other realisations of it
    arrangement: Arrangement | None = None  # a prior over how the recipe's strands lie (arrangement.py)

    @property
    def hair(self) -> HairParams:
        """The hair of the target's scenes: the values of the controls that are not fitted."""
        return self.images[0].scene.hair

    @property
    def origin(self) -> str:
        """Who rendered the images: target.toml's renderer, or "unknown" where it says warp-hair (the default) but
        an image's header lacks warp-hair's own render record (`render_metadata`: a version, no peer renderer)."""
        if self.renderer != "warp-hair":
            return self.renderer
        for image in self.images:
            record = image.metadata.get("warp_hair")
            if not (isinstance(record, dict) and "version" in record and "renderer" not in record):
                return "unknown"
        return "warp-hair"


def made_by(origin: str) -> str:
    """`Target.origin` in words: "rendered by cycles", or "of unknown origin" (a photograph, an EXR from elsewhere)."""
    return "of unknown origin" if origin == "unknown" else f"rendered by {origin}"


def interpenetration_note(target: Target, model_error: float | None = None) -> str | None:
    """A warning for the fit's report when the target's strands pass through each other and another renderer (or
    an unknown one) made its images: renderers disagree there (docs/scenes.md, "Interpenetrating strands"), and the
    σ's model error (`model_error`, the relative brightness disagreement the fit counts, when given) need not cover
    it: on a groom made in Blender 9 of 100 components fell beyond 2σ where warp-hair's own render of it gave 1
    (docs/acceptance.md, "The Blender groom, 20 seeds")."""
    if target.origin == "warp-hair":
        return None  # rendered under the very rule the fit renders with
    for image in target.images:
        report = checked_interpenetration(image.scene.fibers)
        if report.pairs:
            rule = image.scene.render.interpenetration
            return (
                f"the target's strands interpenetrate ({report.pairs} pairs of {report.num_strands} strands) and its "
                f"images were {made_by(target.origin)}: renderers disagree there (issue 23's swatch: 2-18% in "
                f'image means). This fit renders with [render] interpenetration = "{rule}"; a Cycles 4.x CPU '
                'render needs "exit", Mitsuba 3 "enter" (docs/scenes.md, "Interpenetrating strands")'
            ) + (
                ""
                if model_error is None
                else f". Its σ counts a {100 * model_error:g}% model error (--model-error), which need not cover "
                "that disagreement: on a groom made in Blender, 9 of 100 components fell beyond 2σ "
                '(docs/acceptance.md, "The Blender groom, 20 seeds")'
            )
    return None


def read_target_spec(directory) -> list[dict]:
    """The [[images]] entries of a target directory's target.toml, checked for shape (not for the files)."""
    return _read_spec(directory)["images"]


def target_renderer(directory) -> str:
    """Which renderer made the target's images (target.toml's `renderer`, default "warp-hair")."""
    return _read_spec(directory).get("renderer", "warp-hair")


def _read_spec(directory) -> dict:
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: target directory not found")
    spec_path = directory / TARGET_FILE
    try:
        spec = tomllib.loads(spec_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileNotFoundError(
            f"{spec_path}: not found; a target directory needs a {TARGET_FILE} listing its images"
        ) from None
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{spec_path}: cannot read: {error}") from None
    except tomllib.TOMLDecodeError as error:
        raise ValueError(f"{spec_path}: TOML syntax error: {error}") from None
    unknown = sorted(set(spec) - SPEC_KEYS)
    if unknown:
        raise ValueError(
            f"{spec_path}: unknown key(s) {unknown}; a target file has [[images]] tables, renderer, "
            "gains, white_balance, realisations, [card] and [arrangement]"
        )
    for key, allowed in (
        ("gains", GAIN_MODES),
        ("white_balance", WHITE_BALANCE_MODES),
        ("realisations", REALISATION_MODES),
    ):
        if key in spec and spec[key] not in allowed:
            raise ValueError(f"{spec_path}: {key} = {spec[key]!r}; allowed: {list(allowed)}")
    if spec.get("renderer", "warp-hair") not in RENDERERS:
        raise ValueError(f"{spec_path}: renderer = {spec['renderer']!r}; allowed: {list(RENDERERS)}")
    entries = spec.get("images")
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise ValueError(f"{spec_path}: needs at least one [[images]] table with scene = ... and image = ...")
    for k, entry in enumerate(entries):
        where = f"{spec_path}: [[images]] #{k + 1}"
        unknown = sorted(set(entry) - IMAGE_KEYS)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(IMAGE_KEYS)}")
        for key in ("scene", "image"):
            if not isinstance(entry.get(key), str) or not entry[key]:
                raise ValueError(f'{where}: needs {key} = "<file name>"')
        if "mask" in entry and not isinstance(entry["mask"], str):
            raise ValueError(f"{where}: mask must be a file name, got {entry['mask']!r}")
        if "transfer" in entry and entry["transfer"] not in TRANSFERS:
            raise ValueError(f"{where}: transfer = {entry['transfer']!r}; allowed: {list(TRANSFERS)}")
        _check_card_entry(spec, entry, where)
    if "card" in spec and not any("card_mask" in entry for entry in entries):
        raise ValueError(
            f"{spec_path}: [card] describes a grey card but no [[images]] table names its pixels (card_mask = "
            '"<mask file>"); add one, or leave [card] out'
        )
    return spec


def _check_card_entry(spec: dict, entry: dict, where: str) -> None:
    """A grey card marked in an image (card_region.py): its mask file, and a description of it at hand."""
    if "card_mask" in entry and (not isinstance(entry["card_mask"], str) or not entry["card_mask"]):
        raise ValueError(f"{where}: card_mask must be a file name, got {entry['card_mask']!r}")
    if "card" in entry and "card_mask" not in entry:
        raise ValueError(f'{where}: card = ... describes a grey card but the image names no card_mask = "<file>"')
    if "card_mask" in entry and "card" not in spec and "card" not in entry:
        raise ValueError(
            f"{where}: card_mask names a grey card's pixels but nothing says what the card is: add a [card] table "
            '(reflectance = 0.18 or [r, g, b]; normal = "camera" or [x, y, z]) or card = {...} to the image'
        )


def _card_description(spec: dict, entry: dict, where: str) -> dict:
    """The image's card: target.toml's [card], its keys overridden by the image's own card = {...}."""
    table = spec.get("card", {})
    if not isinstance(table, dict):
        raise ValueError(f"{where}: [card] must be a table with reflectance = ... and normal = ...")
    own = entry.get("card", {})
    if not isinstance(own, dict):
        raise ValueError(f"{where}: card must be a table {{reflectance = ..., normal = ...}}, got {own!r}")
    return card_region.description({**table, **own}, f"{where}: card")


def load_target(directory) -> Target:
    """Read and check a target directory (see the module docstring); errors name the file and the problem."""
    directory = Path(directory)
    spec = _read_spec(directory)
    images = []
    for k, entry in enumerate(spec["images"]):
        scene = load_scene(directory / entry["scene"])
        image_path = directory / entry["image"]
        image, metadata, photo = _read_target_image(image_path, scene, entry.get("transfer", "auto"))
        mask = None if "mask" not in entry else _read_mask(directory / entry["mask"], image.shape[:2])
        if photo is not None:
            mask = _photo_mask(photo, mask)
        card = None
        if "card_mask" in entry:
            where = f"{directory / TARGET_FILE}: [[images]] #{k + 1}"
            marked = _read_mask(directory / entry["card_mask"], image.shape[:2])
            card = card_region.region(marked, _card_description(spec, entry, where), scene, image, photo, where)
            mask = ~marked if mask is None else mask & ~marked  # the card's pixels are not hair
            if not mask.any():
                raise ValueError(f"{where}: no pixel of hair is left once the card's ({entry['card_mask']}) are out")
        images.append(TargetImage(Path(entry["image"]).stem, scene, image, mask, image_path, metadata, photo, card))
    _check_consistent(images)
    if spec.get("realisations") == "random":
        for image in images:
            check_realisable(image.scene, f'{directory / TARGET_FILE}: realisations = "random"')
    arrangement = None
    if "arrangement" in spec:
        if spec.get("realisations") != "random":
            raise ValueError(
                f"{directory / TARGET_FILE}: [arrangement] is a prior over the realisations of a recipe; it needs "
                'realisations = "random"'
            )
        arrangement = arrangement_prior(spec["arrangement"], [image.scene for image in images], directory / TARGET_FILE)
    truth = read_truth(directory / TRUTH_FILE)
    gains, white_balance = _camera_unknowns(directory / TARGET_FILE, spec, images)
    return Target(
        directory.resolve().name,
        directory,
        images,
        truth,
        spec.get("renderer", "warp-hair"),
        gains,
        white_balance,
        spec.get("realisations", "fixed"),
        arrangement,
    )


def _photo_mask(photo, mask):
    """The given mask (or every pixel) without the photo's clipped and crushed pixels; an error if none is left."""
    keep = ~(photo.clipped | photo.crushed)
    combined = keep if mask is None else (mask & keep)
    if not combined.any():
        raise ValueError(
            f"{photo.path}: every pixel{' the mask selects' if mask is not None else ''} is clipped "
            f"({int(photo.clipped.sum())}) or crushed to black ({int(photo.crushed.sum())}): nothing "
            "is left to fit; expose the photo so that the hair lies within the range"
        )
    return combined


def _camera_unknowns(spec_path: Path, spec: dict, images) -> tuple:
    """(gains, white_balance) for the fit (optimize/camera.py): target.toml's, else, where any image is
    display-referred or camera raw (a camera chose its exposure and white balance), both fitted, a gain per image
    (EXIF's ratios tie them only where the views' lights were alike, which target.toml's gains = "exif" says);
    for linear images (EXR, linear TIFF), none."""
    photos = [image.photo for image in images]
    # A grey card marked in an image is there to pin the gains: with one, they are unknowns even in an EXR.
    display = any(p is not None and p.camera_exposed for p in photos) or any(im.card is not None for im in images)
    with_exif = all(image.relative_exposure is not None for image in images)
    gains = spec.get("gains", "per-image" if display else "none")
    white_balance = spec.get("white_balance", "fit" if display else "none")
    if gains == "none" and white_balance == "none" and any(im.card is not None for im in images):
        raise ValueError(
            f'{spec_path}: a grey card is marked (card_mask) but gains = "none" and white_balance = "none": the '
            "card pins the photos' gains and white balance, and there are none to pin; fit them, or leave the "
            "card out"
        )
    if gains == "exif" and not with_exif:
        lacking = next(image for image in images if image.relative_exposure is None)
        raise ValueError(
            f'{spec_path}: gains = "exif" but {lacking.image_path.name} has no EXIF exposure time, '
            'f-number and ISO to relate its exposure to the others\'; use gains = "per-image"'
        )
    return gains, white_balance


def _read_target_image(path: Path, scene: Scene, transfer: str = "auto") -> tuple:
    """(linear image, EXR metadata, Photo or None): an EXR as it is, a PNG, JPEG or TIFF decoded (warp_hair.photo)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: target image not found")
    photo = None
    if path.suffix.lower() == ".exr":
        if transfer not in ("auto", "linear"):
            raise ValueError(f"{path}: an EXR holds linear values; transfer = {transfer!r} does not apply")
        image, metadata = read_exr(path)
    else:
        photo = read_photo(path, transfer)
        image, metadata = photo.image, {}
    width, height = scene.camera.resolution
    if image.shape[:2] != (height, width):
        raise ValueError(
            f"{path}: the image is {image.shape[1]}x{image.shape[0]} pixels but {scene.path.name}'s camera renders "
            f"{width}x{height}; render the target with that camera or set its resolution"
        )
    bad = ~np.isfinite(image)
    if bad.any():
        y, x, c = np.argwhere(bad)[0]
        raise ValueError(
            f"{path}: {int(bad.sum())} NaN or infinite value(s), the first at pixel (x={x}, y={y}), channel {'RGB'[c]}"
        )
    if (image < 0).any():
        y, x, c = np.argwhere(image < 0)[0]
        raise ValueError(
            f"{path}: negative radiance {image[y, x, c]} at pixel (x={x}, y={y}); targets are linear radiance >= 0"
        )
    return image, metadata, photo


def _read_mask(path: Path, shape) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mask not found")
    if path.suffix.lower() == ".exr":
        mask = read_exr(path)[0][..., 0] > 0.5
    else:
        from PIL import Image, UnidentifiedImageError

        try:
            mask = np.asarray(Image.open(path).convert("L")) > 127
        except (UnidentifiedImageError, OSError) as error:
            raise ValueError(f"{path}: cannot read the mask: {error}") from None
    if mask.shape != tuple(shape):
        raise ValueError(f"{path}: the mask is {mask.shape[1]}x{mask.shape[0]} but its image is {shape[1]}x{shape[0]}")
    if not mask.any():
        raise ValueError(f"{path}: the mask selects no pixel")
    return mask


def _check_consistent(images) -> None:
    first = images[0]
    for other in images[1:]:
        pair = f"{first.scene.path.name} and {other.scene.path.name}"
        if other.scene.hair.to_table() != first.scene.hair.to_table():
            raise ValueError(f"{pair} have different [hair] tables; the images of a target show one hair")
        a, b = first.scene.fibers, other.scene.fibers
        if a.points.shape != b.points.shape or not (
            np.array_equal(a.points, b.points) and np.array_equal(a.radii, b.radii)
        ):
            raise ValueError(f"{pair} have different fibers; the images of a target show the same fibers")


def read_truth(path: Path) -> HairParams | None:
    """A target's truth.json (its true controls), None where there is none; a ValueError naming the file else."""
    if not path.exists():
        return None
    try:
        controls = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: cannot read the true controls: {error}") from None
    if not isinstance(controls, dict):
        raise ValueError(f"{path}: must hold an object of control name -> value")
    try:
        return HairParams.from_dict(controls, where=str(path))
    except ValueError as error:
        message = str(error)
        raise ValueError(message if str(path) in message else f"{path}: {message}") from None


def make_target(directory, threads=None, progress=None) -> list[Path]:
    """Render every image of a target from its scene file and write truth.json; returns the files written.

    Each image is rendered at its scene's [render] spp and seed, so a target is reproduced exactly (the
    renderer's result does not depend on the thread count). progress(done, total) counts pixels over all images.
    """
    directory = Path(directory)
    entries = read_target_spec(directory)
    _check_writable_target(directory)
    renderer = target_renderer(directory)
    if any(Path(entry["image"]).suffix.lower() != ".exr" for entry in entries):
        raise ValueError(
            f"{directory}: its images are photos (or made to look like them), not renders to remake; "
            "the shipped photo-like targets are remade with `python benchmarks/make_photo_targets.py`"
        )
    if renderer != "warp-hair":
        raise ValueError(
            f"{directory}: its images were rendered by {renderer}; re-render them with "
            f"`python benchmarks/make_peer_targets.py {directory.name}` (from a source checkout, with "
            f"{renderer} installed)"
        )
    scenes = [load_scene(directory / entry["scene"]) for entry in entries]
    total = sum(s.camera.resolution[0] * s.camera.resolution[1] for s in scenes)
    written, done = [], 0
    for entry, scene in zip(entries, scenes):
        offset = done

        def report(pixels, _total, offset=offset):
            if progress is not None:
                progress(offset + pixels, total)

        image = render(scene, spp=scene.render.spp, seed=scene.render.seed, threads=threads, progress=report)
        # Record the scene's own file rather than its absolute paths: the header must not depend on the checkout.
        meta = render_metadata(scene, scene.render.spp, scene.render.seed)
        meta["warp_hair"]["scene"] = entry["scene"]
        path = directory / entry["image"]
        write_exr(path, image, meta)
        written.append(path)
        done += scene.camera.resolution[0] * scene.camera.resolution[1]
    _check_consistent([TargetImage("", s, None, None, Path()) for s in scenes])
    truth = directory / TRUTH_FILE
    truth.write_text(json.dumps(scenes[0].hair.to_table(), indent=2) + "\n", encoding="utf-8")
    written.append(truth)
    return written


def _check_writable_target(directory: Path) -> None:
    """An installed package's shipped targets are its data, not a working copy: they are remade in a checkout."""
    if shipped.is_source_checkout() or directory.resolve().parent != SHIPPED_TARGETS.resolve():
        return
    raise ValueError(
        f"{directory}: a shipped target of the installed warp-hair package, which is not rewritten; "
        f"remake it in a source checkout, or copy the directory elsewhere and make the copy "
        f"(`cp -r {directory} my_target && warp-hair targets make my_target`)"
    )


def shipped_targets() -> list[Path]:
    """The shipped target directories (the `targets` package), sorted by name."""
    return [shipped.path(name) for name in shipped.names()]


def true_values(target: Target, names) -> dict:
    """The true values of the fitted controls where the target has truth.json (exposure's truth is 1)."""
    if target.truth is None:
        return {}
    truth = target.truth.to_dict()
    truth[EXPOSURE] = 1.0
    return {name: truth[name] for name in names if name in truth}


def fix_controls(target, fixed: dict) -> None:
    for image in target.images:
        values = {name: v if SPECS[name].size == 3 else v[0] for name, v in fixed.items()}
        hair = HairParams.from_dict({**image.scene.hair.to_table(), **values}, where="--fix")
        image.scene = dataclasses.replace(image.scene, hair=hair)


def resolve_target(name_or_path: str) -> Path:
    """A target directory, or else the shipped target of that name (the `targets` package)."""
    import targets

    path = Path(name_or_path)
    if path.exists():
        return path
    if name_or_path in targets.names():
        return targets.path(name_or_path)
    raise FileNotFoundError(
        f"{name_or_path}: no such target directory, nor a shipped target (shipped: {', '.join(targets.names())})"
    )
