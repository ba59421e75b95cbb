"""The fuzz's cases and their checks, shared by tests/test_fuzz.py (a few hundred, in-process) and
benchmarks/fuzz.py (thousands, each in a forked child with limits): seeded mutations of the shipped scenes, fiber
files, hair controls, target directories and photos (`cases(seed, n)`), one case run and judged (`run_case`), and
the isolation of a case in a child (`start_isolated`, `finish_isolated`, `run_all`).

Each outcome must be a project error (ValueError or OSError) whose message names the input (the file, or the
table and key), or, for inputs that load, a finite render (BSDF values for hair controls) that is not black where
the mutation cannot darken the image (hair controls, render settings). A photo (the shipped photo-like targets'
pixels saved in odd ways: greyscale, alpha, 1-bit, palette, 16-bit, CMYK, progressive, restart markers; then
truncated, a byte changed, or a huge size in its header) must be an error naming it, or decode to the pixels its
unchanged file gives; only a JPEG, which has no checksum, may decode damaged (DAMAGED_JPEG, counted apart: the
"JPEG data" area changes one byte of its entropy-coded data, to measure how much of that libjpeg sees).
"""

from __future__ import annotations

import copy
import json
import math
import os
import random
import resource
import shutil
import signal
import struct
import time
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SCENES = [
    *sorted(ROOT.glob("targets/*/scene_*.toml")),
    ROOT / "examples" / "swatch.toml",
    ROOT / "benchmarks" / "standard_swatch.toml",
]
TARGETS = sorted(p.parent for p in ROOT.glob("targets/*/target.toml"))
# The photo-like targets' photos (64x64 RGB, as a camera saves them), the sources of the photo areas' files.
PHOTOS = sorted(ROOT.glob("targets/photo_*/*.png")) + sorted(ROOT.glob("targets/photo_*/*.jpg"))
FILE_AREAS = ("scene", "scene text", "text fibers", ".hair fibers", "hair controls", "target")
PHOTO_AREAS = ("photo", "JPEG data")
AREAS = FILE_AREAS + PHOTO_AREAS
# Outcomes that pass; every other one is a failure.
BLACK_ABSORBING = "image (black: the hair absorbs everything)"
# JPEG has no checksum: a changed byte after which its entropy-coded data falls back in step decodes to wrong
# blocks in any decoder. A PNG has a CRC on every chunk: a damaged one that decodes is a failure.
DAMAGED_JPEG = "damaged JPEG decoded (no checksum to see it)"
PASSING = (
    "error naming the input",
    "image",
    "image (black: geometry, light or camera changed)",
    BLACK_ABSORBING,
    "finite BSDF",
    "loaded",
    "photo",
    "photo (the change did not reach the pixels)",
    DAMAGED_JPEG,
)
# Renders of valid mutants are kept tiny: the fuzz is after failures, not pictures.
RENDER_PIXELS, RENDER_SPP, RENDER_DEPTH = 16, 2, 6

HOSTILE_NUMBERS = [
    0,
    -0.0,
    -1,
    0.5,
    2,
    1e-320,
    1e-40,
    1e-15,
    1e-6,
    1e6,
    1e15,
    1e20,
    1e39,
    1e300,
    math.nan,
    math.inf,
    -math.inf,
    2**31,
    2**32,
    2**63 - 1,
    10**30,
    True,
    False,
    "0.5",
    "",
    [],
    [1.0, 2.0],
    [1e39, 1e39, 1e39],
    {},
    [0.0, 0.0, 0.0],
    [1e-320, 0.0, 0.0],
    [1e308, 1e308, 1e308],
]
FACTORS = [0.0, -1.0, 1e-6, 0.1, 0.5, 2.0, 10.0, 1e6, 1e30]
HAIR_KEYS = ("albedo", "sigma_a", "eumelanin", "pheomelanin", "beta_m", "beta_n", "alpha", "eta", "r_roughness_scale")
TEXT_TOKENS = ["nan", "inf", "-inf", "1e30", "1e39", "-1", "0", "1e-40", "abc", "", "1e400", "0x10", "1,5", "\ufeff1"]


@dataclass
class Case:
    area: str
    index: int
    source: str  # the shipped file it mutates
    mutation: str  # what was done, for the report
    data: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------------------------
# Mutations


def _paths(value, prefix=()):
    """Every (path, leaf) in a TOML-like dict, lists of numbers counted as leaves."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _paths(item, (*prefix, key))
    elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        for k, item in enumerate(value):
            yield from _paths(item, (*prefix, k))
    else:
        yield prefix, value


def _scaled(value, factor):
    if isinstance(value, bool) or not isinstance(value, (int, float, list)):
        return factor
    if isinstance(value, list):
        return [_scaled(v, factor) for v in value]
    scaled = value * factor
    return int(scaled) if isinstance(value, int) and math.isfinite(scaled) else scaled


def _mutate_dict(data, rng):
    data = copy.deepcopy(data)
    leaves = [p for p, _ in _paths(data) if p]
    kind = rng.random()
    path = rng.choice(leaves)
    table = data
    for key in path[:-1]:
        table = table[key]
    key = path[-1]
    if kind < 0.55:
        value = copy.deepcopy(rng.choice(HOSTILE_NUMBERS))
        table[key] = value
        what = f"{'.'.join(map(str, path))} = {value!r}"
    elif kind < 0.85:
        factor = rng.choice(FACTORS)
        table[key] = _scaled(table[key], factor)
        what = f"{'.'.join(map(str, path))} × {factor:g}"
    elif kind < 0.95:
        del table[key]
        what = f"delete {'.'.join(map(str, path))}"
    else:
        table[key + "_extra" if isinstance(key, str) else "extra"] = 1.0
        what = f"add a key beside {'.'.join(map(str, path))}"
    return data, path, what


def _scene_case(index, rng):
    source = rng.choice(SCENES)
    data = tomllib.loads(source.read_text())
    mutant, path, what = _mutate_dict(data, rng)
    return Case(
        "scene",
        index,
        source.relative_to(ROOT).as_posix(),
        what,
        {"scene": mutant, "key": str(path[-1]), "table": str(path[0]), "base": str(source.parent)},
    )


def _scene_text_case(index, rng):
    source = rng.choice(SCENES)
    lines = source.read_text().splitlines()
    k = rng.randrange(len(lines))
    choice = rng.random()
    if choice < 0.4:
        del lines[k]
        what = f"delete line {k + 1}"
    elif choice < 0.7:
        lines.insert(k, lines[k])
        what = f"repeat line {k + 1}"
    elif choice < 0.85:
        lines[k] = lines[k][: rng.randrange(len(lines[k]) + 1)]
        what = f"cut line {k + 1}"
    else:
        lines[k] = lines[k].replace("=", "= [", 1)
        what = f"break line {k + 1}"
    return Case(
        "scene text",
        index,
        source.relative_to(ROOT).as_posix(),
        what,
        {"text": "\n".join(lines) + "\n", "base": str(source.parent)},
    )


def _fiber_strands(rng):
    from warp_hair.geometry.generators import swatch

    return swatch(count=rng.randint(2, 8), layers=1, segments=rng.randint(1, 4), seed=rng.randrange(100))


def _text_fiber_case(index, rng):
    from warp_hair.geometry.formats import write_text

    fibers = _fiber_strands(rng)
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"fuzz-{os.getpid()}-{index}.txt"
    write_text(fibers, path)
    text = path.read_text()
    path.unlink()
    lines = text.splitlines()
    choice = rng.random()
    k = rng.randrange(1, len(lines))
    if choice < 0.5:
        tokens = lines[k].split()
        if tokens:
            tokens[rng.randrange(len(tokens))] = rng.choice(TEXT_TOKENS)
        lines[k] = " ".join(tokens)
        what = f"line {k + 1} → {lines[k]!r}"
    elif choice < 0.65:
        del lines[k]
        what = f"delete line {k + 1}"
    elif choice < 0.75:
        lines.insert(k, "")
        what = f"blank line before {k + 1}"
    elif choice < 0.85:
        lines[0] = "\ufeff" + lines[0]
        what = "byte-order mark"
    else:
        lines[k] = lines[k] + " 1"
        what = f"fifth number on line {k + 1}"
    raw = ("\n".join(lines) + "\n").encode()
    if rng.random() < 0.05:
        raw = raw[: rng.randrange(len(raw))] + b"\xff\xfe"
        what += ", bytes that are not UTF-8"
    return Case("text fibers", index, "swatch(…) as text", what, {"bytes": raw.hex(), "suffix": ".txt"})


# Byte offsets of the .hair header's fields (Cem Yuksel's format, little-endian).
HAIR_FIELDS = {
    "strands": (4, "<I"),
    "points": (8, "<I"),
    "flags": (12, "<I"),
    "default segments": (16, "<I"),
    "default thickness": (20, "<f"),
}


def _hair_fiber_case(index, rng):
    from warp_hair.geometry.formats import write_hair

    fibers = _fiber_strands(rng)
    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"fuzz-{os.getpid()}-{index}.hair"
    write_hair(fibers, path)
    raw = bytearray(path.read_bytes())
    path.unlink()
    choice = rng.random()
    if choice < 0.4:
        name = rng.choice(list(HAIR_FIELDS))
        offset, fmt = HAIR_FIELDS[name]
        value = (
            rng.choice([0, 1, 2, 3, 7, 31, 2**16, 2**31, 2**32 - 1])
            if fmt == "<I"
            else rng.choice([0.0, -1.0, 1e-40, 1e38, math.inf, math.nan, 1e20])
        )
        struct.pack_into(fmt, raw, offset, value)
        what = f"header {name} = {value!r}"
    elif choice < 0.65:
        k = rng.randrange(128, len(raw))
        raw[k] = rng.randrange(256)
        what = f"byte {k} = {raw[k]}"
    elif choice < 0.8:
        cut = rng.randrange(len(raw))
        raw = raw[:cut]
        what = f"truncated to {cut} bytes"
    elif choice < 0.9:
        extra = rng.randrange(1, 64)
        raw += bytes(extra)
        what = f"{extra} bytes appended"
    else:
        k = rng.randrange(128 + 2 * fibers.num_strands, len(raw) - 4, 4)
        struct.pack_into("<f", raw, k, rng.choice([math.nan, math.inf, 1e30, -1e38, 1e-45]))
        what = f"float at byte {k} = {struct.unpack_from('<f', raw, k)[0]!r}"
    return Case(".hair fibers", index, "swatch(…) as .hair", what, {"bytes": bytes(raw).hex(), "suffix": ".hair"})


def _hair_controls_case(index, rng):
    colour = rng.choice(["albedo", "sigma_a", "eumelanin", "pheomelanin"])
    controls = {colour: rng.choice([0.3, [0.6, 0.4, 0.2], 1.0, 0.0, 8.0])}
    if colour == "albedo" and controls[colour] == 0.0:
        controls[colour] = 0.5
    for key in rng.sample(HAIR_KEYS[4:], rng.randint(0, 3)):
        controls[key] = rng.choice([0.0, 0.01, 0.3, 1.0, 1.5, 30.0, 1 + 1e-9, 10.0])
    key = rng.choice(HAIR_KEYS)
    value = copy.deepcopy(rng.choice([*HOSTILE_NUMBERS, 1 + 1e-09, 1e-40, 1e40, 3.5e38, 1e-07]))
    controls[key] = value
    return Case("hair controls", index, "HairParams", f"{controls!r}", {"controls": controls, "key": key})


def _target_case(index, rng):
    source = rng.choice(TARGETS)
    choice = rng.random()
    if choice < 0.5:
        truth = json.loads((source / "truth.json").read_text())
        mutant, _, what = _mutate_dict({"truth": truth}, rng)
        data = {"truth.json": json.dumps(mutant.get("truth", {}))}
        what = f"truth.json: {what}"
    elif choice < 0.8:
        spec = tomllib.loads((source / "target.toml").read_text())
        mutant, _path, what = _mutate_dict(spec, rng)
        data = {"target.toml": _toml(mutant)}
        what = f"target.toml: {what}"
    else:
        # The target's images as target.toml lists them: EXR, or a photo-like target's PNG or JPEG.
        name = rng.choice([entry["image"] for entry in tomllib.loads((source / "target.toml").read_text())["images"]])
        raw = (source / name).read_bytes()
        cut = rng.randrange(len(raw))
        data = {name + ".bytes": raw[:cut].hex()}
        what = f"{name} truncated to {cut} bytes"
    return Case("target", index, source.relative_to(ROOT).as_posix(), what, {"files": data, "source": str(source)})


def _toml(spec) -> str:
    """A target.toml of [[images]] tables (the only shape it has), written back from its dict."""
    out = []
    for key, value in spec.items():
        if key == "images" and isinstance(value, list) and all(isinstance(v, dict) for v in value):
            for entry in value:
                out.append("[[images]]")
                out += [f"{k} = {json.dumps(v)}" for k, v in entry.items() if _plain(v)]
        elif _plain(value):
            out.insert(0, f"{key} = {json.dumps(value)}")
    return "\n".join(out) + "\n"


def _plain(value):
    try:
        text = json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return not isinstance(value, dict) and text != "null"


# The photos' variants: (name, suffix); each made from a shipped photo's pixels (`_variant`).
VARIANTS = (
    ("as shipped", None),
    ("greyscale", ".png"),
    ("grey and alpha", ".png"),
    ("RGBA, opaque", ".png"),
    ("RGBA, one pixel translucent", ".png"),
    ("1-bit", ".png"),
    ("palette", ".png"),
    ("16-bit RGB", ".png"),
    ("16-bit grey", ".png"),
    ("16-bit RGBA, opaque", ".png"),
    ("CMYK", ".jpg"),
    ("greyscale", ".jpg"),
    ("progressive", ".jpg"),
    ("restart markers", ".jpg"),
)
JPEG_VARIANTS = [v for v in VARIANTS if v[1] in (None, ".jpg") and v[0] != "CMYK"]


def _variant(source: Path, name: str, suffix) -> tuple[bytes, str]:
    """(file bytes, suffix): `source`'s pixels saved as the variant says."""
    import io

    import png
    from PIL import Image

    if suffix is None:
        return source.read_bytes(), source.suffix
    with Image.open(source) as im:
        rgb = np.asarray(im.convert("RGB"))
    buffer = io.BytesIO()
    h, w = rgb.shape[:2]
    if name.startswith("16-bit"):
        wide = rgb.astype(np.uint16) * 256 + np.arange(w, dtype=np.uint16)[None, :, None]  # low bytes too
        grey = name == "16-bit grey"
        rows = wide[..., :1] if grey else wide
        if "RGBA" in name:
            rows = np.dstack([wide, np.full((h, w), 65535, np.uint16)])
        png.Writer(w, h, bitdepth=16, greyscale=grey, alpha="RGBA" in name).write(buffer, rows.reshape(h, -1))
        return buffer.getvalue(), suffix
    image = Image.fromarray(rgb)
    if suffix == ".jpg":
        options = {"progressive": name == "progressive", "restart_marker_blocks": 4 if "restart" in name else 0}
        mode = {"CMYK": "CMYK", "greyscale": "L"}.get(name, "RGB")
        image.convert(mode).save(buffer, "JPEG", quality=90, **options)
        return buffer.getvalue(), suffix
    if name.startswith("RGBA") or name == "grey and alpha":
        alpha = np.full((h, w), 255, np.uint8)
        alpha[h // 2, w // 2] = 128 if "translucent" in name else 255
        base = image.convert("L") if name.startswith("grey") else image
        image = Image.merge(base.mode + "A", [*base.split(), Image.fromarray(alpha)])
    else:
        image = image.convert({"greyscale": "L", "1-bit": "1", "palette": "P"}[name])
    image.save(buffer, "PNG")
    return buffer.getvalue(), suffix


def _scan_data(raw: bytes) -> tuple[int, int]:
    """Where a JPEG's entropy-coded data lies: after the first start-of-scan header, up to the end of image."""
    start = raw.index(b"\xff\xda")
    return start + 2 + int.from_bytes(raw[start + 2 : start + 4], "big"), raw.rindex(b"\xff\xd9")


def _flip(raw: bytes, rng, start=0, end=None) -> tuple[bytes, str]:
    raw = bytearray(raw)
    k = rng.randrange(start, len(raw) if end is None else end)
    value = rng.choice([v for v in range(256) if v != raw[k]])
    what = f"byte {k} {raw[k]:#04x} -> {value:#04x}"
    raw[k] = value
    return bytes(raw), what


def _huge(raw: bytes, suffix: str) -> bytes:
    """The header says 100000x100000 (PNG, its CRC made right) or 65500x65500 (JPEG's first frame header)."""
    import zlib

    raw = bytearray(raw)
    if suffix == ".png":
        struct.pack_into(">II", raw, 16, 100000, 100000)
        struct.pack_into(">I", raw, 29, zlib.crc32(bytes(raw[12:29])))
    else:
        frame = next(raw.index(m) for m in (b"\xff\xc0", b"\xff\xc2", b"\xff\xc1") if m in raw)
        struct.pack_into(">HH", raw, frame + 5, 65500, 65500)
    return bytes(raw)


def _photo_case(index, rng):
    source = rng.choice(PHOTOS)
    name, suffix = rng.choice([v for v in VARIANTS if v[1] in (None, source.suffix)])
    original, suffix = _variant(source, name, suffix)
    choice = rng.random()
    if choice < 0.25:
        raw, what = original, "as it is"
    elif choice < 0.5:
        cut = rng.randrange(len(original))
        raw, what = original[:cut], f"truncated to {cut} bytes"
    elif choice < 0.85:
        raw, what = _flip(original, rng)
    else:
        raw, what = _huge(original, suffix), "header declares a huge image"
    data = {"bytes": raw.hex(), "original": original.hex(), "suffix": suffix}
    return Case("photo", index, source.relative_to(ROOT).as_posix(), f"{name} {suffix}: {what}", data)


def _jpeg_data_case(index, rng):
    """One byte of a JPEG's entropy-coded data changed: what libjpeg reports is an error, the rest is DAMAGED_JPEG."""
    source = rng.choice([p for p in PHOTOS if p.suffix == ".jpg"])
    name, suffix = rng.choice(JPEG_VARIANTS)
    original, suffix = _variant(source, name, suffix or ".jpg")
    raw, what = _flip(original, rng, *_scan_data(original))
    data = {"bytes": raw.hex(), "original": original.hex(), "suffix": suffix}
    return Case("JPEG data", index, source.relative_to(ROOT).as_posix(), f"{name}: {what}", data)


MAKERS = {
    "scene": _scene_case,
    "scene text": _scene_text_case,
    "text fibers": _text_fiber_case,
    ".hair fibers": _hair_fiber_case,
    "hair controls": _hair_controls_case,
    "target": _target_case,
    "photo": _photo_case,
    "JPEG data": _jpeg_data_case,
}
# Relative frequency of each area.
WEIGHTS = {
    "scene": 4,
    "scene text": 1,
    "text fibers": 2,
    ".hair fibers": 2,
    "hair controls": 3,
    "target": 1,
    "photo": 2,
    "JPEG data": 1,
}


def cases(seed: int, n: int, areas=AREAS, first: int = 0) -> list[Case]:
    """n seeded cases of `areas`, mixed in proportion to WEIGHTS, numbered from `first`. The photo areas draw from
    a stream of their own, so that adding them left the other areas' cases as they were."""
    groups = [[a for a in group if a in areas] for group in (FILE_AREAS, PHOTO_AREAS)]
    weights = [sum(WEIGHTS[a] for a in group) for group in groups]
    counts = [round(n * w / sum(weights)) for w in weights[:-1]]
    counts.append(n - sum(counts))
    made = []
    for stream, (group, count) in enumerate(zip(groups, counts)):
        rng = random.Random(seed if stream == 0 else f"{seed}/photos")
        pool = [a for a in group for _ in range(WEIGHTS[a])]
        made += [MAKERS[rng.choice(pool)](first + len(made) + k, rng) for k in range(count)]
    return made


# ---------------------------------------------------------------------------------------------------------------
# Running one case


def run_case(case: Case, workdir: Path) -> tuple[str, str]:
    """(outcome, detail) of one case; outcomes not in PASSING are failures."""
    import warnings

    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the β floor's warning is expected for some mutants
        try:
            return RUNNERS[case.area](case, workdir)
        except (ValueError, OSError) as error:
            return ("unnamed error", f"{type(error).__name__}: {error}")
        except MemoryError as error:
            return ("MemoryError", str(error))
        except Exception as error:
            return ("crash", f"{type(error).__name__}: {error}")


def _named(error, *names) -> tuple[str, str]:
    text = str(error)
    if any(name and name in text for name in names):
        return ("error naming the input", text)
    return ("unnamed error", text)


def _rendered(scene, may_be_black) -> tuple[str, str]:
    import dataclasses

    import warp_hair as wh

    width, height = scene.camera.resolution
    shrink = max(1, math.ceil(max(width, height) / RENDER_PIXELS))
    camera = dataclasses.replace(scene.camera, resolution=(max(1, width // shrink), max(1, height // shrink)))
    settings = dataclasses.replace(
        scene.render,
        max_depth=min(scene.render.max_depth, RENDER_DEPTH),
        rr_depth=min(scene.render.rr_depth, RENDER_DEPTH),
    )
    scene = dataclasses.replace(scene, camera=camera, render=settings)
    image = wh.render(scene, spp=RENDER_SPP, threads=1)
    if not np.isfinite(image).all():
        return ("NaN or Inf in the image", f"{int((~np.isfinite(image)).sum())} values")
    if image.max() <= 0:
        return ("image (black: geometry, light or camera changed)", "") if may_be_black else ("black image", "")
    return ("image", f"mean {image.mean():.3g}")


def _run_scene(case, workdir):
    from warp_hair.scene import scene_from_dict

    where = "mutant.toml"
    try:
        scene = scene_from_dict(case.data["scene"], base_dir=case.data["base"], where=where)
    except (ValueError, OSError) as error:
        return _named(error, where) if str(error).startswith(where) else ("unnamed error", str(error))
    outcome = _rendered(scene, may_be_black=case.data["table"] not in ("hair", "render"))
    if outcome[0] == "black image" and case.data["table"] == "hair":
        # Black hair lit from behind is black: then the same scene with non-absorbing fibers must show them.
        import dataclasses

        white = dataclasses.replace(scene, hair=scene.hair.replace(sigma_a=0.0))
        if _rendered(white, may_be_black=False)[0] == "image":
            return (BLACK_ABSORBING, f"σ_a = {scene.hair.absorption.tolist()}")
    return outcome


def _run_scene_text(case, workdir):
    from warp_hair.scene import load_scene

    base = Path(case.data["base"])
    path = workdir / f"mutant-{case.index}.toml"
    text = case.data["text"]
    # Relative file names point where the shipped scene's do.
    for name in ("standard_swatch_fibers.txt",):
        text = text.replace(f'"{name}"', json.dumps(str(base / name)))
    path.write_text(text)
    try:
        scene = load_scene(path)
    except (ValueError, OSError) as error:
        return _named(error, str(path)) if str(error).startswith(str(path)) else ("unnamed error", str(error))
    finally:
        path.unlink()
    return _rendered(scene, may_be_black=True)


def _run_fibers(case, workdir):
    from warp_hair.geometry.formats import load_fibers
    from warp_hair.scene import scene_from_dict

    path = workdir / f"mutant-{case.index}{case.data['suffix']}"
    path.write_bytes(bytes.fromhex(case.data["bytes"]))
    try:
        try:
            load_fibers(path)
        except (ValueError, OSError) as error:
            return _named(error, str(path))
        scene = {
            "camera": {
                "type": "orthographic",
                "origin": [0.0, 0.0, 3.0],
                "target": [0.0, 0.0, 0.0],
                "up": [0.0, 1.0, 0.0],
                "width": 0.2,
                "resolution": [16, 16],
            },
            "lights": [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {"file": str(path)},
            "hair": {"eumelanin": 1.3},
        }
        try:
            loaded = scene_from_dict(scene, where="fuzz.toml")
        except ValueError as error:  # the fibers load, but e.g. their scale does not suit float32
            return _named(error, "fuzz.toml")
        return _rendered(loaded, may_be_black=True)
    finally:
        path.unlink()


# Directions at the edges of the sphere and a few inside, for the BSDF checks.
_AXES = np.array(
    [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [0.6, 0.8, 0], [0.3, 0.4, 0.866]]
)


def _run_hair_controls(case, workdir):
    import warp_hair as wh
    from warp_hair.model.params import HairParams

    try:
        params = HairParams(**case.data["controls"])
    except ValueError as error:
        return _named(error, *case.data["controls"], "colour input")  # any control given may be the bad one
    axes = _AXES / np.linalg.norm(_AXES, axis=1, keepdims=True)
    wo, wi = np.repeat(axes, len(axes), axis=0), np.tile(axes, (len(axes), 1))
    u = np.random.default_rng(case.index).uniform(size=(len(wo), 3))
    total = 0.0
    for h in (-1.0, -0.3, 0.0, 0.7, 1.0):
        value = wh.bsdf.eval(params, wo, wi, h)
        density = wh.bsdf.pdf(params, wo, wi, h)
        w, weight, sample_density = wh.bsdf.sample(params, wo, h, u)
        arrays = (value, density, w, weight, sample_density)
        if not all(np.isfinite(a).all() for a in arrays):
            return ("NaN or Inf from the BSDF", f"h = {h}")
        if (value < 0).any() or (density < 0).any():
            return ("negative BSDF value", f"h = {h}")
        total += float(value.sum())
    return ("finite BSDF", "") if total > 0 else ("black BSDF", "")


def _run_target(case, workdir):
    from optimize.target import load_target

    directory = workdir / f"target-{case.index}"
    shutil.copytree(case.data["source"], directory)
    try:
        for name, content in case.data["files"].items():
            if name.endswith(".bytes"):
                (directory / name[: -len(".bytes")]).write_bytes(bytes.fromhex(content))
            else:
                (directory / name).write_text(content)
        try:
            load_target(directory)
        except (ValueError, OSError) as error:
            return _named(error, str(directory))
        return ("loaded", "")
    finally:
        shutil.rmtree(directory, ignore_errors=True)


def _run_photo(case, workdir):
    """read_photo on the file: an error naming it, or a photo; a changed file that decodes to other pixels than
    its original is a failure unless it is a JPEG (DAMAGED_JPEG)."""
    from warp_hair.photo import read_photo

    path = workdir / f"mutant-{case.index}{case.data['suffix']}"
    original = workdir / f"original-{case.index}{case.data['suffix']}"
    path.write_bytes(bytes.fromhex(case.data["bytes"]))
    original.write_bytes(bytes.fromhex(case.data["original"]))
    try:
        try:
            photo = read_photo(path)
        except (ValueError, OSError) as error:
            return _named(error, str(path))
        if not np.isfinite(photo.image).all() or photo.image.min() < 0:
            return ("photo with values out of range", f"{photo.image.min()} to {photo.image.max()}")
        if case.data["bytes"] == case.data["original"]:
            return ("photo", f"{photo.format} {photo.bits}-bit {photo.notes}")
        try:
            reference = read_photo(original).image
        except (ValueError, OSError):
            reference = None
        if reference is not None and np.array_equal(reference, photo.image):
            return ("photo (the change did not reach the pixels)", "")
        if case.data["suffix"] == ".jpg":
            return (DAMAGED_JPEG, "")
        return ("damaged photo decoded", f"{photo.format} {photo.bits}-bit")
    finally:
        path.unlink()
        original.unlink()


RUNNERS = {
    "scene": _run_scene,
    "scene text": _run_scene_text,
    "text fibers": _run_fibers,
    ".hair fibers": _run_fibers,
    "hair controls": _run_hair_controls,
    "target": _run_target,
    "photo": _run_photo,
    "JPEG data": _run_photo,
}


# ---------------------------------------------------------------------------------------------------------------
# The isolated run: one forked child per case, with limits


def _mapped_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def start_isolated(case: Case, workdir: Path, memory: int, seconds: int):
    """Fork a child that runs `case` under RLIMIT_AS (what the parent maps plus `memory` bytes) and RLIMIT_CPU
    (`seconds`); returns (pid, pipe, wall-clock deadline) for `finish_isolated`."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child
        os.close(read_end)
        # Libraries (OpenEXR) print their own complaints, on stdout and stderr, about damaged files; the outcome says
        # what happened.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        try:
            limit = _mapped_bytes() + memory
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            resource.setrlimit(resource.RLIMIT_CPU, (seconds, seconds + 1))
            outcome = run_case(case, workdir)
        except BaseException as error:
            outcome = ("crash", f"{type(error).__name__}: {error}")
        os.write(write_end, json.dumps(outcome).encode()[:60000])
        os._exit(0)
    os.close(write_end)
    return pid, read_end, time.monotonic() + 2 * seconds


def finish_isolated(pid, read_end, deadline):
    """The child's outcome once it has exited, "hang" if it passed its deadline (it is killed), else None."""
    done, status = os.waitpid(pid, os.WNOHANG)
    if not done:
        if time.monotonic() < deadline:
            return None
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        os.close(read_end)
        return ("hang", "killed at its wall-clock limit")
    with os.fdopen(read_end, "rb") as pipe:
        data = pipe.read()
    if not data:
        how = f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else f"exit {os.WEXITSTATUS(status)}"
        return ("child died", how)
    return tuple(json.loads(data))


def run_all(all_cases, workdir, memory, seconds, jobs, bar):
    """Every case in its own child, `jobs` at a time (a single-threaded parent: nothing is locked at a fork)."""
    results, running, queue = {}, {}, list(enumerate(all_cases))
    try:
        while queue or running:
            while queue and len(running) < jobs:
                k, case = queue.pop(0)
                running[k] = start_isolated(case, workdir, memory, seconds)
            for k in list(running):
                outcome = finish_isolated(*running[k])
                if outcome is not None:
                    del running[k]
                    results[k] = (all_cases[k], outcome)
                    bar.update()
            time.sleep(0.002)
    finally:
        for pid, read_end, _ in running.values():
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            os.close(read_end)
    return [results[k] for k in sorted(results)]


def warm_up(workdir):
    """Compile and load the kernels once in the parent, so that children inherit them instead of compiling."""
    import optimize.target  # noqa: F401  (imported here, not in each child)
    import warp_hair as wh

    case = Case("hair controls", -1, "", "", {"controls": {"albedo": 0.5}, "key": "albedo"})
    run_case(case, workdir)
    scene = wh.scene_from_dict(tomllib.loads(SCENES[0].read_text()), base_dir=SCENES[0].parent)
    _rendered(scene, may_be_black=True)


def table(results) -> str:
    """Markdown: cases per area (rows) and outcome (columns)."""
    counts = Counter((case.area, outcome) for case, (outcome, _) in results)
    outcomes = [o for o in PASSING if any(k[1] == o for k in counts)]
    outcomes += sorted({o for _, o in counts} - set(PASSING))
    lines = ["| area | cases | " + " | ".join(outcomes) + " |", "| --- | --- |" + " --- |" * len(outcomes)]
    for area in AREAS:
        row = [counts[(area, o)] for o in outcomes]
        if sum(row):
            lines.append(f"| {area} | {sum(row)} | " + " | ".join(str(v) for v in row) + " |")
    lines.append(
        f"| all | {len(results)} | " + " | ".join(str(sum(counts[(a, o)] for a in AREAS)) for o in outcomes) + " |"
    )
    return "\n".join(lines)
