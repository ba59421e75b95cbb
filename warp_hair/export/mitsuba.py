"""Mitsuba 3: the look as a `hair` BSDF, a `mitsuba.load_dict` dictionary or the XML element `load_string` reads.

    from warp_hair.export.mitsuba import bsdf_dict, bsdf_xml
    mi.load_dict({"type": "scene", ..., "hair": {"type": "bsplinecurve", "filename": ..., "bsdf": bsdf_dict(look)}})

Conversion (Mitsuba 3.9, src/bsdfs/hair.cpp, class Hair: the constructor's properties and `update()`):
- `sigma_a` (rgb): Mitsuba has no albedo input, so an albedo look is inverted here with the talk's formula at
  the fitted β_n (`warp_hair.model.params.sigma_a_from_albedo`); melanin looks are given as their σ_a too. Mitsuba's
  σ_a is per unit fiber radius (`absorption()` uses it unscaled, with `scale` 1), as ours. Exact in the RGB
  variants; spectral variants upsample the RGB coefficient.
- `longitudinal_roughness`, `azimuthal_roughness` = β_m, β_n: `update()` applies the talk's mappings, with
  √(π/8) on the logistic scale, as ours. Mitsuba does not floor them; ours renders β < 0.01 as 0.01, so the
  floored value is written.
- `scale_tilt` = −α in degrees: `reframe_with_scales` rotates the R lobe by −2α like pbrt (common.py).
- `int_ior` = η and `ext_ior` = 1: Mitsuba's η is int_ior / ext_ior and ext_ior defaults to air (1.000277).
- No R-roughness scale: a scale other than 1 is dropped with a LossyExportWarning (`WRITES`).
- One look for every strand, root to tip: a look's variation (color_spread, roughness_spread, tip_absorption,
  tip_length; model/variation.py) is dropped with a LossyExportWarning (`NO_VARIATION`); the Cycles export
  keeps it.

Render it on `bsplinecurve` with a polyline's vertices as control points: Mitsuba's `linearcurve` hands the
BSDF a frame whose tangent is not the fiber's (docs/MODEL.md), and both shapes flip the tangent with the side of
the fiber hit, so the tilt acts with opposite signs on the two halves of a fiber. Expect light hair to render
about 2% brighter there when lit from the front: Mitsuba's `Hair::sample` draws the residual lobe in the fiber's
normal plane only (docs/MODEL.md, "The peers as references"; `benchmarks/mitsuba_residual_lobe.py` shows it),
which the exported look cannot change.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

from ..model.params import HairParams
from .common import (
    NO_R_ROUGHNESS_SCALE,
    NO_VARIATION,
    declared,
    fmt,
    roughness,
    sigma_a,
    tilt_degrees,
    warn_unwritten,
    writes,
)

NAME = "mitsuba"
SUFFIX = ".xml"
# The scene-description version `load_string` needs on a root element.
XML_VERSION = "3.0.0"
# What the hair BSDF gets of each control (common.py, `declared`); the docstring above says how.
WRITES = declared(
    NAME,
    {
        "albedo": writes("sigma_a", note="the talk's inversion at β_n"),
        "sigma_a": writes("sigma_a"),
        "eumelanin": writes("sigma_a", note="d'Eon's coefficients"),
        "pheomelanin": writes("sigma_a", note="d'Eon's coefficients"),
        "beta_m": writes("longitudinal_roughness"),
        "beta_n": writes("azimuthal_roughness"),
        "alpha": writes("scale_tilt", note="−α"),
        "eta": writes("int_ior", note="ext_ior = 1"),
        "r_roughness_scale": NO_R_ROUGHNESS_SCALE,
        **NO_VARIATION,
    },
)


def bsdf_dict(params: HairParams) -> dict:
    """The `hair` BSDF as a `mitsuba.load_dict` dictionary."""
    warn_unwritten(params, NAME, WRITES)
    beta_m, beta_n = roughness(params)
    return {
        "type": "hair",
        "sigma_a": {"type": "rgb", "value": sigma_a(params)},
        "longitudinal_roughness": beta_m,
        "azimuthal_roughness": beta_n,
        "scale_tilt": tilt_degrees(params, NAME),
        "int_ior": float(params.eta),
        "ext_ior": 1.0,
    }


def bsdf_xml(params: HairParams, bsdf_id: str = "hair") -> str:
    """The `<bsdf type="hair">` element (with the `version` attribute `mitsuba.load_string` needs)."""
    d = bsdf_dict(params)
    rgb = ", ".join(fmt(c) for c in d["sigma_a"]["value"])
    floats = [(k, v) for k, v in d.items() if k not in ("type", "sigma_a")]
    lines = [
        f"<!-- warp-hair look for Mitsuba 3 (hair BSDF); controls: {params.to_dict()} -->",
        f'<bsdf type="hair" id={quoteattr(bsdf_id)} version="{XML_VERSION}">',
        f'    <rgb name="sigma_a" value="{rgb}"/>',
        *(f'    <float name="{k}" value="{fmt(v)}"/>' for k, v in floats),
        "</bsdf>",
    ]
    return "\n".join(lines) + "\n"


export_text = bsdf_xml
