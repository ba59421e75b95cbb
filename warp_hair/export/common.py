"""What the exporters share: the controls as every renderer's hair model takes them, and how they report loss.

Each exporter declares, for every control of `warp_hair.controls.CONTROLS`, what it writes it as (`Writes`, the
renderer's parameter names) or why it cannot (`Cannot`, which is also the warning a look that sets it gets):
`WRITES = declared(NAME, {...})`, which stops the import when a control of the table is missing or a name is not
one, so that a control added to the table cannot be dropped silently by an exporter (as model/jacobian.py stops
for a control without its derivative).

Tilt sign, stated once for all exporters: warp-hair's α > 0 is the physical cuticle tilt (docs/MODEL.md, "Cuticle
tilt"): for strands listed root first, the R lobe shifts toward the root (it peaks at θ_i + θ_o = −2α with θ
positive toward the tip). Blender Cycles' `Offset` and MaterialX's `cuticle_angle` rotate the same way;
pbrt-v4's `alpha` and Mitsuba 3's `scale_tilt` rotate the other way, so they get −α (`TILT_SIGN`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import controls as table
from ..model.params import HairParams, effective_beta

# The sign each renderer's tilt parameter takes relative to ours (see the module docstring).
TILT_SIGN = {"mitsuba": -1.0, "pbrt": -1.0, "cycles": 1.0, "materialx": 1.0}


class LossyExportWarning(UserWarning):
    """The target renderer cannot express part of the look exactly; the message says what it renders instead."""


def lossy(renderer: str, message: str) -> None:
    warnings.warn(f"{renderer} export: {message}", LossyExportWarning, stacklevel=3)


@dataclass(frozen=True)
class Writes:
    """The renderer's parameter(s) a control goes into, and a brief note on how."""

    parameters: tuple
    note: str = ""


@dataclass(frozen=True)
class Cannot:
    """A control the renderer cannot express. A look that moves it off its default is exported without it and
    warned: "{reason}: {control} = {value} is dropped ({instead})"; with `only_with`, only when that control is off
    its default too (without it this one changes nothing)."""

    reason: str
    instead: str
    only_with: str | None = None


def writes(*parameters: str, note: str = "") -> Writes:
    return Writes(parameters, note)


# Mitsuba's and pbrt's hair models have no counterpart of our R-roughness scale.
NO_R_ROUGHNESS_SCALE = Cannot(
    "it has no R-roughness scale", "its R lobe gets the longitudinal roughness of β_m unscaled"
)


# A hair model with one look for every fiber (pbrt-v4's HairBxDF, Mitsuba 3's hair, MaterialX's chiang_bsdf):
# the variation's controls (model/variation.py) are dropped, every strand gets the material's own look, root to tip.
_KEPT_BY_CYCLES = "the Cycles export keeps it"
NO_VARIATION = {
    "color_spread": Cannot(
        "it has one look for every strand", f"every strand gets the material's colour; {_KEPT_BY_CYCLES}"
    ),
    "roughness_spread": Cannot(
        "it has one look for every strand", f"every strand gets the material's roughness; {_KEPT_BY_CYCLES}"
    ),
    "tip_absorption": Cannot(
        "it has no root-to-tip change", f"the root's absorption runs to the tip; {_KEPT_BY_CYCLES}"
    ),
    "tip_length": Cannot(
        "it has no root-to-tip change",
        f"the root's absorption runs to the tip; {_KEPT_BY_CYCLES}",
        only_with="tip_absorption",
    ),
}


def declared(renderer: str, declaration: dict) -> dict:
    """`declaration` ({control: Writes or Cannot}, for `renderer`), checked against the table of controls: an
    ImportError names the controls it lacks or does not know."""
    missing = [name for name in table.CONTROL_NAMES if name not in declaration]
    unknown = sorted(set(declaration) - set(table.CONTROL_NAMES))
    wrong = [name for name, what in declaration.items() if not isinstance(what, (Writes, Cannot))]
    empty = [name for name, what in declaration.items() if isinstance(what, Writes) and not what.parameters]
    problems = [
        f"{what} {names}"
        for what, names in (
            ("declares nothing for the controls", missing),
            ("declares controls the table does not have:", unknown),
            ("declares neither Writes nor Cannot for", wrong),
            ("names no parameter for", empty),
        )
        if names
    ]
    if problems:
        raise ImportError(
            f"warp_hair/export/{renderer}.py {'; '.join(problems)} (the table: {list(table.CONTROL_NAMES)})"
        )
    return {name: declaration[name] for name in table.CONTROL_NAMES}


def _shown(value) -> str:
    values = np.atleast_1d(np.asarray(value, dtype=np.float64))
    return f"{values[0]:g}" if values.size == 1 else "(" + ", ".join(f"{v:g}" for v in values) + ")"


def _set(params: HairParams, name: str) -> bool:
    """Whether the look gives the control a value other than its default."""
    value = getattr(params, name)
    return value is not None and bool(np.any(np.asarray(value) != table.CONTROLS[name].default))


def warn_unwritten(params: HairParams, renderer: str, declaration: dict) -> None:
    """Warn for each control the renderer cannot express that the look sets (given, and not its default), unless
    it only acts with another control (`Cannot.only_with`) the look leaves at its default."""
    for name, what in declaration.items():
        if isinstance(what, Cannot) and _set(params, name) and (what.only_with is None or _set(params, what.only_with)):
            lossy(renderer, f"{what.reason}: {name} = {_shown(getattr(params, name))} is dropped ({what.instead})")


def roughness(params: HairParams) -> tuple[float, float]:
    """(β_m, β_n) as warp-hair renders them: below BETA_FLOOR the lobes are those of the floor, so that is
    what an exporter writes (renderers whose own floor is lower would render a narrower lobe)."""
    return float(effective_beta(params.beta_m)), float(effective_beta(params.beta_n))


def tilt_degrees(params: HairParams, renderer: str) -> float:
    return TILT_SIGN[renderer] * params.alpha


def sigma_a(params: HairParams) -> list[float]:
    """The absorption per unit fiber radius, whatever the colour input (the albedo inversion at β_n)."""
    return [float(s) for s in params.absorption]


def fmt(x: float) -> str:
    """The shortest text that reads back as the same double."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"cannot export the non-finite value {x}")
    return repr(x)
