"""Take a look to the renderers people render with: Mitsuba 3, pbrt-v4, Blender Cycles and MaterialX.

    warp-hair export fit/params.json --to mitsuba -o hair.xml      # or pbrt, cycles, materialx; stdout without -o

    from warp_hair.export import export, load_look
    text = export("fit/params.json", to="cycles")                  # a LOOK path, or a HairParams

A LOOK is a fit's params.json (its "look": every control, fitted and fixed), a JSON object of controls (a
target's truth.json), or a scene file (its [hair] table). Each renderer names, parametrises and signs the model
differently; each module converts (its docstring says from which source code), declares in its `WRITES`, control
by control, what it writes or why it cannot (checked against the table of controls when it is imported), and warns
with a `LossyExportWarning` where the renderer cannot express a control. `controls_table()` is that declaration as
the table docs/export.md shows. The tilt sign convention is stated once, in `warp_hair.export.common`.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from ..controls import CONTROL_NAMES
from ..io import read_text
from ..model.params import HairParams
from . import cycles, materialx, mitsuba, pbrt
from .common import Cannot, LossyExportWarning

RENDERERS = {module.NAME: module for module in (mitsuba, pbrt, cycles, materialx)}
# The key of a fit's params.json (optimize/report.py) that holds every control of the fitted look.
LOOK_KEY = "look"

__all__ = [
    "RENDERERS",
    "LossyExportWarning",
    "controls_table",
    "default_filename",
    "export",
    "load_look",
    "parse_renderers",
    "renderer",
]


def renderer(name: str):
    """The exporter module for a renderer's name, or a ValueError listing the names."""
    try:
        return RENDERERS[name]
    except KeyError:
        raise ValueError(f"unknown renderer {name!r} to export to; choose one of {', '.join(RENDERERS)}") from None


def parse_renderers(names: str) -> list[str]:
    """ "mitsuba,cycles" → ["mitsuba", "cycles"], each checked."""
    chosen = [n.strip() for n in names.split(",") if n.strip()]
    if not chosen:
        raise ValueError(f"no renderer to export to; choose from {', '.join(RENDERERS)}")
    for name in chosen:
        renderer(name)
    return chosen


def default_filename(to: str) -> str:
    """The file name an export gets beside a fit's params.json, e.g. hair_mitsuba.xml."""
    return f"hair_{to}{renderer(to).SUFFIX}"


def load_look(path) -> HairParams:
    """The hair controls of a LOOK file: params.json, a JSON object of controls, or a scene file's [hair]."""
    path = Path(path)
    text = read_text(path, "look file", " (give a fit's params.json or a scene file)")
    if path.suffix.lower() == ".toml":
        try:
            table = tomllib.loads(text).get("hair")
        except tomllib.TOMLDecodeError as error:
            raise ValueError(f"{path}: not a valid scene file: {error}") from None
        if not isinstance(table, dict):
            raise ValueError(f"{path}: the scene file has no [hair] table to export")
        return _controls(table, f"{path} [hair]")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not a JSON look nor a .toml scene file: {error}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a JSON look must be an object of controls, got {type(data).__name__}")
    if LOOK_KEY in data:
        if not isinstance(data[LOOK_KEY], dict):
            raise ValueError(f'{path}: "{LOOK_KEY}" must be an object of controls')
        return _controls(data[LOOK_KEY], f'{path} "{LOOK_KEY}"')
    if "fitted" in data:
        raise ValueError(
            f'{path}: this params.json has no "{LOOK_KEY}" (every control of the fitted look); '
            "it was written by an older warp-hair: refit, or export the target's scene file"
        )
    if not set(data) <= set(CONTROL_NAMES):
        raise ValueError(
            f'{path}: neither a fit\'s params.json (no "{LOOK_KEY}") nor an object of hair controls '
            f"(unknown keys {sorted(set(data) - set(CONTROL_NAMES))})"
        )
    return _controls(data, str(path))


def _controls(table: dict, where: str) -> HairParams:
    try:
        return HairParams.from_dict(table, where=where)
    except (TypeError, ValueError) as error:
        message = str(error)
        raise ValueError(message if where in message else f"{where}: {message}") from None


def export(look, to: str, path=None) -> str:
    """The look (a HairParams or a LOOK path) as `to`'s file text; written to `path` too when given."""
    module = renderer(to)
    params = look if isinstance(look, HairParams) else load_look(look)
    text = module.export_text(params)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text


def _cell(what) -> str:
    if isinstance(what, Cannot):
        return f"not written ({what.reason}): dropped with a warning"
    names = ", ".join(f"`{name}`" for name in what.parameters)
    return f"{names}: {what.note}" if what.note else names


def controls_table() -> str:
    """Every control and what each renderer's export makes of it (the modules' `WRITES`), as a Markdown table."""
    rows = [
        "| control | " + " | ".join(RENDERERS) + " |",
        "|---" * (1 + len(RENDERERS)) + "|",
        *(
            f"| `{name}` | " + " | ".join(_cell(module.WRITES[name]) for module in RENDERERS.values()) + " |"
            for name in CONTROL_NAMES
        ),
    ]
    return "\n".join(rows) + "\n"
