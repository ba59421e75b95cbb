"""pbrt-v4: the look as a `Material "hair"` directive for a scene file.

Conversion (pbrt-v4 src/pbrt/materials.cpp `HairMaterial::Create`, materials.h `HairMaterial::GetBxDF`,
bxdfs.cpp `HairBxDF::HairBxDF`):
- `"rgb sigma_a"`: the absorption per unit fiber radius, as ours; an albedo look is inverted here at the fitted
  β_n (`warp_hair.model.params.sigma_a_from_albedo`). This is the exact one: pbrt's own `reflectance` (alias `color`)
  is an albedo *spectrum*, clamped to [0, 1] and upsampled from RGB, and `HairBxDF::SigmaAFromReflectance`
  inverts it per wavelength: that is not the per-channel inversion of the RGB albedo ours does. (pbrt renders
  spectrally either way: the RGB coefficient itself is upsampled as an unbounded spectrum.)
- `"float beta_m"`, `"float beta_n"`: pbrt clamps both to [0.01, 1] (GetBxDF), as ours; its mappings are the
  talk's, with √(π/8) on the logistic scale.
- `"float alpha"` = −α in degrees: HairBxDF rotates the R lobe by −2α (common.py states the sign convention).
- `"float eta"` = η.
- No R-roughness scale: a scale other than 1 is dropped with a LossyExportWarning (`WRITES`).
- One look for every strand, root to tip: a look's variation (color_spread, roughness_spread, tip_absorption,
  tip_length; model/variation.py) is dropped with a LossyExportWarning (`NO_VARIATION`); the Cycles export
  keeps it.

pbrt reads the fiber offset h from the curve's v coordinate: use it on `Shape "curve" "string type" "cylinder"`.
"""

from __future__ import annotations

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

NAME = "pbrt"
SUFFIX = ".pbrt"
# What the hair material gets of each control (common.py, `declared`); the docstring above says how.
WRITES = declared(
    NAME,
    {
        "albedo": writes("rgb sigma_a", note="the talk's inversion at β_n"),
        "sigma_a": writes("rgb sigma_a"),
        "eumelanin": writes("rgb sigma_a", note="d'Eon's coefficients"),
        "pheomelanin": writes("rgb sigma_a", note="d'Eon's coefficients"),
        "beta_m": writes("float beta_m"),
        "beta_n": writes("float beta_n"),
        "alpha": writes("float alpha", note="−α"),
        "eta": writes("float eta"),
        "r_roughness_scale": NO_R_ROUGHNESS_SCALE,
        **NO_VARIATION,
    },
)


def material_parameters(params: HairParams) -> dict:
    """{pbrt parameter declaration ("rgb sigma_a", "float beta_m", ...): list of values}."""
    warn_unwritten(params, NAME, WRITES)
    beta_m, beta_n = roughness(params)
    return {
        "rgb sigma_a": sigma_a(params),
        "float beta_m": [beta_m],
        "float beta_n": [beta_n],
        "float alpha": [tilt_degrees(params, NAME)],
        "float eta": [float(params.eta)],
    }


def material_text(params: HairParams) -> str:
    lines = [f"# warp-hair look for pbrt-v4 (hair material); controls: {params.to_dict()}", 'Material "hair"']
    for declaration, values in material_parameters(params).items():
        lines.append(f'    "{declaration}" [ {" ".join(fmt(v) for v in values)} ]')
    return "\n".join(lines) + "\n"


export_text = material_text
