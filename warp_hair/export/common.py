"""What the exporters share: the controls as every renderer's hair model takes them, and how they report loss.

Tilt sign, stated once for all exporters: warp-hair's α > 0 is the physical cuticle tilt (docs/MODEL.md, "Cuticle
tilt"): for strands listed root first, the R lobe shifts toward the root (it peaks at θ_i + θ_o = −2α with θ
positive toward the tip). Blender Cycles' `Offset` and MaterialX's `cuticle_angle` rotate the same way;
pbrt-v4's `alpha` and Mitsuba 3's `scale_tilt` rotate the other way, so they get −α (`TILT_SIGN`).
"""

from __future__ import annotations

import math
import warnings

from ..model.params import HairParams, effective_beta

# The sign each renderer's tilt parameter takes relative to ours (see the module docstring).
TILT_SIGN = {"mitsuba": -1.0, "pbrt": -1.0, "cycles": 1.0, "materialx": 1.0}


class LossyExportWarning(UserWarning):
    """The target renderer cannot express part of the look exactly; the message says what it renders instead."""


def lossy(renderer: str, message: str) -> None:
    warnings.warn(f"{renderer} export: {message}", LossyExportWarning, stacklevel=3)


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


def no_r_roughness_scale(params: HairParams, renderer: str) -> None:
    if params.r_roughness_scale != 1.0:
        lossy(
            renderer,
            f"it has no R-roughness scale: r_roughness_scale = {params.r_roughness_scale:g} is "
            "dropped (its R lobe gets the longitudinal roughness of β_m unscaled)",
        )
