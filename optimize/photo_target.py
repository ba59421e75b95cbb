"""A fit target from photographs, in one command: the rig's dimensions, the camera, the light, the photos.

    warp-hair targets photo OUT_DIR --rig draped --image front.jpg --light 0.2,-0.3,-1 \\
        --image back.jpg --light 0,-0.15,1 --width 0.4 --length 0.5 --count 152 --layers 4 --drape 0.25 \\
        --distance 3 --sensor-width 23.5 --resolution 64
    warp-hair fit OUT_DIR -o fit_out

writes OUT_DIR/scene_<photo>.toml (camera, light, fibers, a starting [hair]), <photo>.exr (the photo decoded to
linear and box-filtered down to the working resolution), <photo>_mask.png where pixels are left out, and
target.toml with the photos' gains and white balance to fit (`optimize/camera.py`).

The rig's frame is the generators' (warp_hair.geometry.generators): fibers run along +y (roots at −length/2),
across x, the camera on +z looking at the origin (the top of the rod, for a draped swatch; the card's face, for
a flat swatch; for a fur patch the camera looks down at the patch from `--elevation` degrees above its plane).
A directional light's vector is the direction its light travels, in that frame: (0.2, −0.3, −1) comes from
behind the camera, a little above and to the left; (0, −0.15, 1) from behind the swatch. An HDRI taken where the
swatch stood (`--hdri`, a lat-long EXR in the rig's frame: +y up the image, u = 0 looking away from the camera,
docs/scenes.md) lights every view; `--light` given with it adds its directional light per photo (a flash or the
sun besides the room).

Rigs: `draped` a swatch laid over a rod of radius `--drape` (the highlight band a photo shows), `flat` a swatch
on a card, `fur` a patch of fur (`--patch`, `--fur-length`, `--count`). A swatch's fibers are straight unless
`--waves AMPLITUDE,WAVELENGTH` or `--curls RADIUS,PITCH` (the wavy and curly generators, with
`--phase-jitter` and `--layer-phase-jitter`), and may gather into `--clumps N` (`--clump-strength`) and have
`--strays N` (`--stray-lift`) leave the front surface; a thick swatch is more `--layers` (and `--count`).
The rig's strands are a recipe, never the photographed ones, so target.toml says `realisations = "random"`: the
fit renders other realisations of it (optimize/realisations.py). How a swatch's strands lie, which no photographer
measures (jitter, the gap between layers), is written as a prior the fit averages over and estimates,
target.toml's [arrangement] (optimize/arrangement.py, `photo_defaults`: jitter 0.05 to 0.4, a gap of 2 to 3.75
fiber radii); edit or delete it there. The camera: orthographic (`--ortho-width`,
the view's width in scene units), or perspective at `--distance` with `--fov`, or EXIF's focal length with
`--sensor-width` (mm; the 35 mm equivalent focal length's 36 mm when EXIF gives that). A grey card behind the
swatch (`--card REFLECTANCE`) is rendered as the scenes' [card]: its pixels pin the gains and white balance. A
grey card somewhere in the shot that is not modelled is marked instead: `--card-mask` (per photo, a mask of its
pixels at the photo's size, or 'none'), `--card-reflectance` and `--card-normal` (default facing the camera)
write <photo>_card.png and target.toml's [card] (optimize/card_region.py); its blocks are those wholly on the
card, and blocks it touches are left out of the hair.

Decisions: the photo is box-filtered in linear light to `--resolution` square blocks across its whole width,
any width (a block the area-weighted mean of the pixels and fractions of pixels it covers: `downsample`), and as
many rows of them as fit, centred, so that the target keeps the field and centre the camera describes; a block
holding a clipped or crushed pixel is left out (the mask), as is the background when `--mask auto` (pixels
within 5% of the border's median colour; not with a card, whose pixels carry the light's level and colour). EXIF
that contradicts the flags (a `--fov` more than 2% from the one EXIF's focal length gives) is an error naming
both; a light count that does not match the photos is an error.

The photos' exposures: a gain per photo by default (`--gains per-image`), which leaves each view's brightness
free: with the white balance also free, a light or a dark swatch's overall level then trades with its albedo
(docs/fitting.md). `--gains exif` ties them to one gain and the views' ratios the camera recorded (the APEX
values where the file has them, warp_hair.photo.relative_exposure), which holds where each view's light is as
strong as the others' (one lamp moved round the swatch, as the scenes' lights of equal irradiance say); only the
photographer knows that, so it is never assumed (a note says when every photo has the EXIF to do it).
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from warp_hair.geometry.generators import CURL_SEGMENTS, WAVE_SEGMENTS
from warp_hair.io import write_exr
from warp_hair.photo import read_photo
from warp_hair.scene import GENERATORS, EnvironmentLight

from .arrangement import photo_defaults

RIGS = ("draped", "flat", "fur")
FOV_TOLERANCE = 0.02
BACKGROUND_TOLERANCE = 0.05
# The [render] spp written: a photo's noise (its sensor's, its codes') taken as a 1024-sample render's, as the
# shipped peer targets are; the photo's quantisation is counted apart (identify.py).
PHOTO_SPP = 1024
# Light paths of the [render] written: 32 bounces lose nothing measurable in a swatch of 4 layers, but 12 layers of
# light hair (albedo 0.8, 0.7, 0.5) render 2.1% darker than at 64 (docs/scenes.md, many layers).
MAX_DEPTH, THICK_MAX_DEPTH, THICK_LAYERS = 32, 64, 5
# The swatch generators' keys the flags set, and those flags: a generator's error names the flag the user gave.
FIBER_FLAGS = {
    "count": "--count",
    "layers": "--layers",
    "length": "--length",
    "width": "--width",
    "radius": "--fiber-radius",
    "drape": "--drape",
    "amplitude": "--waves",
    "wavelength": "--waves",
    "curl_radius": "--curls",
    "pitch": "--curls",
    "phase_jitter": "--phase-jitter",
    "layer_phase_jitter": "--layer-phase-jitter",
    "clumps": "--clumps",
    "clump_strength": "--clump-strength",
    "strays": "--strays",
    "stray_lift": "--stray-lift",
}
FUR_FLAGS = {
    "count": "--count",
    "patch": "--patch",
    "length": "--fur-length",
    "root_radius": "--fiber-radius",
    "tip_radius": "--fiber-radius",
}
# The swatch generators' keys that flags of their own name give as they are, and every flag that shapes a swatch's
# fibers, not a fur patch's.
SHAPE_KEYS = ("phase_jitter", "layer_phase_jitter", "clumps", "clump_strength", "strays", "stray_lift")
SWATCH_FLAGS = ("waves", "curls", *SHAPE_KEYS)
START_HAIR = {"albedo": [0.5, 0.5, 0.5], "beta_m": 0.3, "beta_n": 0.3, "alpha": 2.0, "eta": 1.55}


def horizontal_fov(focal_length: float, sensor_width: float) -> float:
    """Degrees: 2 atan(sensor width / 2 f), the pinhole camera's horizontal field of view."""
    return math.degrees(2 * math.atan(sensor_width / (2 * focal_length)))


def camera_fov(photo, fov=None, sensor_width=None) -> float:
    """The horizontal field of view: `fov`, or EXIF's focal length with `sensor_width` (or EXIF's 35 mm
    equivalent over 36 mm); both given and disagreeing by more than FOV_TOLERANCE is an error."""
    exif = photo.exif
    from_exif = None
    if sensor_width is not None and exif.get("focal_length"):
        from_exif = horizontal_fov(exif["focal_length"], sensor_width)
        source = f"EXIF focal length {exif['focal_length']:g} mm on a {sensor_width:g} mm sensor"
    elif exif.get("focal_length_35mm"):
        from_exif = horizontal_fov(exif["focal_length_35mm"], 36.0)
        source = f"EXIF 35 mm equivalent focal length {exif['focal_length_35mm']:g} mm"
    if fov is not None and from_exif is not None and abs(fov / from_exif - 1) > FOV_TOLERANCE:
        raise ValueError(
            f"{photo.path}: --fov {fov:g}° contradicts the {source}, which gives {from_exif:.4g}°; "
            "drop one of them (a crop or a converter may have changed the photo's field of view)"
        )
    if fov is not None:
        return float(fov)
    if from_exif is None:
        if sensor_width is not None:
            raise ValueError(f"{photo.path}: --sensor-width given but the photo has no EXIF focal length; give --fov")
        raise ValueError(
            f"{photo.path}: no field of view: give --fov, or --sensor-width with a photo whose EXIF has "
            "its focal length, or --ortho-width for an orthographic camera"
        )
    return from_exif


def downsample(image: np.ndarray, bad: np.ndarray, width: int) -> tuple:
    """(H, W, 3) linear pixels averaged over `width` equal columns spanning the photo's whole width, and rows of
    the same (square) size, centred, as many as fit: (image, blocks holding any `bad` pixel). Each block is the
    area-weighted mean of the photo pixels it covers, fractions of a pixel counted as such, so the target keeps
    the photo's horizontal field (which the camera's fov or ortho width describe) and its centre (the optical
    axis); less than one block's height is left out, half at the top and half at the bottom."""
    height_in, width_in = image.shape[:2]
    if not 1 <= width <= width_in:
        raise ValueError(f"--resolution {width}: must be between 1 and the photo's width, {width_in} pixels")
    step = width_in / width
    height = int(height_in / step + 1e-9)
    if height < 1:
        raise ValueError(
            f"--resolution {width}: a block of {step:.4g} photo pixels is taller than the photo ({height_in} "
            "pixels); take a larger --resolution"
        )
    rows = _area_weights(height_in, height, (height_in - height * step) / 2, step)
    columns = _area_weights(width_in, width, 0.0, step)
    blocks = np.einsum("yi,ixc,wx->ywc", rows, image.astype(np.float32, copy=False), columns, optimize=True)
    covered = (rows > 0).astype(np.float32), (columns > 0).astype(np.float32)
    flags = covered[0] @ bad.astype(np.float32) @ covered[1].T > 0
    return blocks.astype(np.float32), flags


def _area_weights(n_in: int, n_out: int, start: float, step: float) -> np.ndarray:
    """(n_out, n_in): the share of output pixel k's span [start + k step, start + (k + 1) step) that input pixel
    i's [i, i + 1) covers (each row sums to 1)."""
    edges = start + step * np.arange(n_out + 1)
    pixels = np.arange(n_in)
    overlap = np.minimum(edges[1:, None], pixels + 1.0) - np.maximum(edges[:-1, None], pixels)
    return (np.clip(overlap, 0.0, None) / step).astype(np.float32)


def _read_mask(path: Path, shape, what: str) -> np.ndarray:
    """A mask at the photo's size: white (above half) where it holds."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                if im.size != (shape[1], shape[0]):
                    raise ValueError(
                        f"{path}: the {what} is {im.size[0]}x{im.size[1]} but its photo is {shape[1]}x{shape[0]}"
                    )
                return np.asarray(im.convert("L")) > 127
    except (OSError, SyntaxError, Image.DecompressionBombError, Image.DecompressionBombWarning) as error:
        raise ValueError(f"{path}: cannot read the {what}: {error}") from None


def photo_line(photo, keep: np.ndarray) -> str:
    """What became of a photo: its decoding, the pixels the camera clipped and crushed (count and share), the
    target's pixels left out, and the decoder's notes."""
    pixels = photo.clipped.size
    clipped, crushed = int(photo.clipped.sum()), int((photo.crushed & ~photo.clipped).sum())
    notes = "".join(f"; {note}" for note in photo.notes)
    exif = photo.exif
    if photo.relative_exposure is not None:
        notes = f"; EXIF {exif['exposure_time']:.4g} s, f/{exif['f_number']:g}, ISO {exif['iso']:g}" + notes
    return (
        f"{photo.path.name}: {photo.format} {photo.bits}-bit, {photo.transfer} decoded; {clipped} clipped "
        f"({clipped / pixels:.2%}) and {crushed} crushed ({crushed / pixels:.2%}) of {pixels} pixels; "
        f"{keep.size - int(keep.sum())} of the target's {keep.size} pixels left out{notes}"
    )


def background_mask(image: np.ndarray) -> np.ndarray:
    """True where the pixel differs from the border's median colour by more than BACKGROUND_TOLERANCE of the
    image's 99th percentile (the hair), grown by one pixel."""
    border = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    background = np.median(border, axis=0)
    level = max(float(np.percentile(image, 99)), 1e-12)
    hair = np.abs(image - background).max(axis=-1) > BACKGROUND_TOLERANCE * level
    grown = hair.copy()
    grown[1:] |= hair[:-1]
    grown[:-1] |= hair[1:]
    grown[:, 1:] |= hair[:, :-1]
    grown[:, :-1] |= hair[:, 1:]
    return grown


def _card_masks(args, count: int) -> list:
    """Per photo, its --card-mask file (None for 'none' or without the option), checked against the flags."""
    given = getattr(args, "card_mask", None)
    if not given:
        if getattr(args, "card_reflectance", None) is not None:
            raise ValueError("--card-reflectance given without --card-mask: which pixels are the card?")
        return [None] * count
    if len(given) != count:
        raise ValueError(
            f"{count} photo(s) but {len(given)} --card-mask file(s): give one per --image, in order ('none' "
            "where a photo shows no card)"
        )
    if getattr(args, "card_reflectance", None) is None:
        raise ValueError("--card-mask needs --card-reflectance (an 18% grey card: 0.18): the card's level is its pin")
    return [None if name == "none" else Path(name) for name in given]


def _card_blocks(path: Path, shape, width: int, flags: np.ndarray) -> tuple:
    """(card, touched) at the working resolution from a card mask at the photo's size: the blocks wholly on the
    card and free of clipped or crushed pixels, and every block with a card pixel in it."""
    marked = _read_mask(path, shape, "card mask")
    _, off_card = downsample(np.zeros((*shape, 3), np.float32), ~marked, width)
    _, on_card = downsample(np.zeros((*shape, 3), np.float32), marked, width)
    card = ~off_card & ~flags
    if not card.any():
        step = shape[1] / width
        raise ValueError(
            f"{path}: no block of {step:.4g}x{step:.4g} photo pixels lies wholly on the card and unclipped: mark a "
            "larger part of it, or take a larger --resolution"
        )
    return card, on_card


def _fibers_table(rig: str, args) -> dict:
    """The [fibers] table of the rig and the flags, checked by running its generator (errors name the flag)."""
    table = _rig_fibers(rig, args)
    arguments = {key: value for key, value in table.items() if key != "generator"}
    try:
        GENERATORS[table["generator"]](**arguments)
    except (TypeError, ValueError) as error:
        flags = FUR_FLAGS if rig == "fur" else FIBER_FLAGS
        flag = flags.get(str(error).split(" ")[0], "the rig's fibers")
        raise ValueError(f"{flag}: {error}") from None
    return table


def _rig_fibers(rig: str, args) -> dict:
    given = [name for name in SWATCH_FLAGS if getattr(args, name, None) is not None]
    if rig == "fur" and given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise ValueError(f"{flags}: the swatch rigs' (draped, flat), not --rig fur's")
    if getattr(args, "waves", None) is None and getattr(args, "curls", None) is None:
        waved = [name for name in ("phase_jitter", "layer_phase_jitter") if name in given]
        if waved:
            flags = ", ".join("--" + name.replace("_", "-") for name in waved)
            raise ValueError(f"{flags}: the phases of waves or curls; give --waves or --curls")
    if rig == "fur":
        return {
            "generator": "fur",
            "count": args.count,
            "patch": args.patch,
            "length": args.fur_length,
            "root_radius": args.fiber_radius,
            "tip_radius": args.fiber_radius / 3,
            "seed": 1,
        }
    table = {
        "generator": "swatch",
        "count": args.count,
        "layers": args.layers,
        "length": args.length,
        "width": args.width,
        "radius": args.fiber_radius,
        "segments": 128 if rig == "draped" else 8,
        "jitter": 0.15,
        "seed": 1,
    }
    if rig == "draped":
        table["drape"] = args.drape
    shape = None
    if getattr(args, "waves", None) is not None:
        shape = ("wavy", "amplitude", "wavelength", args.waves, WAVE_SEGMENTS)
    elif getattr(args, "curls", None) is not None:
        shape = ("curly", "curl_radius", "pitch", args.curls, CURL_SEGMENTS)
    if shape is not None:
        generator, size, period, (size_value, period_value), per_period = shape
        table["generator"] = generator
        table[size], table[period] = size_value, period_value
        if period_value > 0 and math.isfinite(period_value):  # else the generator's error names it
            table["segments"] = max(table["segments"], math.ceil(per_period * args.length / period_value))
    for name in SHAPE_KEYS:
        if getattr(args, name, None) is not None:
            table[name] = getattr(args, name)
    return table


def _environment(hdri) -> dict | None:
    """The [[lights]] table of --hdri, the map checked now (read, finite, non-negative) rather than at the fit."""
    if hdri is None:
        return None
    path = Path(hdri).resolve()
    try:
        EnvironmentLight(file=path)
    except ValueError as error:
        raise ValueError(f"--hdri: {str(error).removeprefix('file: ')}") from None
    return {"type": "environment", "file": str(path)}


def _camera_table(rig: str, args, photo, resolution) -> dict:
    if rig == "fur":
        elevation = math.radians(args.elevation)
        direction = np.array([0.0, -math.cos(elevation), math.sin(elevation)])
        up = [0.0, 0.0, 1.0]
    else:
        direction, up = np.array([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]
    origin = (direction * args.distance).round(6).tolist()
    table = {"origin": origin, "target": [0.0, 0.0, 0.0], "up": up, "resolution": list(resolution)}
    if args.ortho_width is not None:
        return {"type": "orthographic", **table, "width": args.ortho_width}
    return {"type": "perspective", **table, "fov": round(camera_fov(photo, args.fov, args.sensor_width), 6)}


def _toml(value) -> str:
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, float) else str(value)


def _table(name: str, table: dict, array: bool = False) -> str:
    head = f"[[{name}]]" if array else f"[{name}]"
    return "\n".join([head] + [f"{key} = {_toml(value)}" for key, value in table.items()])


def make_photo_target(out_dir, args, log=None) -> list[Path]:
    """Write the target (see the module docstring) from the parsed `warp-hair targets photo` arguments; `log`
    (e.g. print) is given a line per photo: its decoding, its clipped and crushed pixels, its notes."""
    out_dir = Path(out_dir)
    images = [Path(p) for p in args.image]
    if args.rig not in RIGS:
        raise ValueError(f"--rig {args.rig!r}; allowed: {list(RIGS)}")
    if (args.hdri is None or args.light) and len(args.light or []) != len(images):
        raise ValueError(
            f"{len(images)} photo(s) but {len(args.light or [])} --light direction(s): give one --light "
            "per --image, in the same order (or --hdri for all)"
        )
    environment = _environment(args.hdri)
    fibers = _fibers_table(args.rig, args)
    if args.mask and len(args.mask) not in (1, len(images)) and args.mask != ["auto"]:
        raise ValueError("--mask takes 'auto' or one mask file per --image")
    card_masks = _card_masks(args, len(images))
    names = [p.stem for p in images]
    if len(set(names)) != len(names):
        raise ValueError(f"two photos have the same name {names}: the target names its files after them")
    out_dir.mkdir(parents=True, exist_ok=True)
    written, entries, with_exif = [], [], 0
    for k, path in enumerate(images):
        photo = read_photo(path, args.transfer)
        if photo.relative_exposure is not None:
            with_exif += 1
        elif args.gains == "exif":  # before this photo's files are written
            raise ValueError(
                f"--gains exif: {path.name} has no EXIF exposure time, f-number and ISO; use --gains per-image"
            )
        bad = photo.clipped | photo.crushed
        image, flags = downsample(photo.image, bad, args.resolution)
        keep = ~flags
        if args.mask == ["auto"] and args.card is None:
            keep &= background_mask(image)
        elif args.mask and args.mask != ["auto"]:
            given = _read_mask(Path(args.mask[k if len(args.mask) > 1 else 0]), photo.image.shape[:2], "mask")
            given, _ = downsample(np.repeat(given[..., None], 3, -1).astype(np.float32), ~given, args.resolution)
            keep &= given[..., 0] > 0.5
        card = None
        if card_masks[k] is not None:
            card, touched = _card_blocks(card_masks[k], photo.image.shape[:2], args.resolution, flags)
            keep &= ~touched  # a block the card reaches is not hair; one it covers only partly is neither
        if not keep.any():
            raise ValueError(f"{path}: no pixel is left to fit once clipped, crushed and background pixels are out")
        resolution = (image.shape[1], image.shape[0])
        if log is not None:
            log(photo_line(photo, keep))
        scene_name, exr_name = f"scene_{path.stem}.toml", f"{path.stem}.exr"
        parts = [
            f"# Made by `warp-hair targets photo` from {path.name} ({photo.format} {photo.bits}-bit, "
            f"{photo.transfer} decoded, {int(photo.clipped.sum())} clipped and {int(photo.crushed.sum())} "
            "crushed pixels left out). [hair] is where a fit starts; the light's level is arbitrary: the fit "
            "solves each photo's gain and the white balance.",
            _table("camera", _camera_table(args.rig, args, photo, resolution)),
        ]
        if environment is not None:
            parts.append(_table("lights", environment, True))
        if args.light:
            parts.append(
                _table(
                    "lights",
                    {"type": "directional", "direction": list(args.light[k]), "irradiance": [3.0, 3.0, 3.0]},
                    True,
                )
            )
        parts += [_table("fibers", fibers), _table("hair", START_HAIR)]
        if args.card is not None:
            parts.append(_table("card", {"albedo": [args.card] * 3}))
        # A photo has no samples: its spp says how noisy `targets check` and the fit's refinement take it to be.
        depth = THICK_MAX_DEPTH if fibers.get("layers", 1) >= THICK_LAYERS else MAX_DEPTH
        parts.append(_table("render", {"spp": PHOTO_SPP, "max_depth": depth, "seed": 1}))
        (out_dir / scene_name).write_text("\n\n".join(parts) + "\n", encoding="utf-8")
        write_exr(
            out_dir / exr_name,
            image,
            {
                "photo": {
                    "file": path.name,
                    "transfer": photo.transfer,
                    "exif": photo.exif,
                    "bits": photo.bits,  # with block, the codes' rounding the fit's χ² counts (goodness.py)
                    "block": photo.image.shape[1] / image.shape[1],  # photo pixels across each target pixel
                }
            },
        )
        entry = {"scene": scene_name, "image": exr_name}
        written += [out_dir / scene_name, out_dir / exr_name]
        if not keep.all():
            mask_name = f"{path.stem}_mask.png"
            Image.fromarray((keep * 255).astype(np.uint8), "L").save(out_dir / mask_name)
            entry["mask"] = mask_name
            written.append(out_dir / mask_name)
        if card is not None:
            entry["card_mask"] = f"{path.stem}_card.png"
            Image.fromarray((card * 255).astype(np.uint8), "L").save(out_dir / entry["card_mask"])
            written.append(out_dir / entry["card_mask"])
        entries.append(entry)
    gains = args.gains
    if gains == "per-image" and len(images) > 1 and with_exif == len(images) and log is not None:
        log(
            "every photo has its EXIF exposure: where one lamp, as strong in every view, lit them all (moved round "
            "the swatch), --gains exif ties their gains to one, which pins the hair's brightness far better"
        )
    lines = [
        "# Made by `warp-hair targets photo`: the photos decoded to linear EXR; their exposures and white balance "
        "are fitted with the hair.",
        *(
            ["# One gain, the views' exposure ratios from EXIF: every view's light as strong as the others'."]
            if gains == "exif"
            else []
        ),
        f"gains = {_toml(gains)}",
        'white_balance = "fit"',
        "# The scenes' [fibers] are the rig's recipe, never the photographed strands: the fit renders other",
        "# realisations of it and counts the photo's strands as one draw in its σ (optimize/realisations.py).",
        'realisations = "random"',
    ]
    if any(mask is not None for mask in card_masks):
        lines += ["", _table("card", {"reflectance": args.card_reflectance, "normal": args.card_normal})]
    prior = photo_defaults(fibers)
    if prior:
        lines += [
            "",
            "# How the strands lie, which a photo does not say: a prior the fit averages over and estimates",
            "# (optimize/arrangement.py); narrow it where you know better.",
            _table("arrangement", prior),
        ]
    for entry in entries:
        lines += ["", "[[images]]"] + [f"{key} = {_toml(value)}" for key, value in entry.items()]
    (out_dir / "target.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    written.append(out_dir / "target.toml")
    if any(mask is not None for mask in card_masks) or prior:
        from .target import load_target

        load_target(out_dir)  # the card checked as a fit will read it: its normal against the camera, its light
    return written
