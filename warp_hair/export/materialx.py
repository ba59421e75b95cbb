"""MaterialX 1.39: the look as a `.mtlx` document with a `chiang_hair_bsdf` in a `surfacematerial`.

Conversion (MaterialX 1.39 libraries/pbrlib/pbrlib_defs.mtlx `ND_chiang_hair_bsdf`, `ND_chiang_hair_roughness`,
`ND_chiang_hair_absorption_from_color`, and their reference implementation
libraries/pbrlib/genglsl/mx_chiang_hair_bsdf.glsl):
- `roughness_R`, `roughness_TT`, `roughness_TRT` are vector2 (longitudinal variance v, logistic scale s), what
  `chiang_hair_roughness` outputs: v = (0.726 β_m + 0.812 β_m² + 3.7 β_m²⁰)² (TT v·0.5², TRT and the residual
  v·2²) and s = 0.265 β_n + 1.194 β_n² + 5.372 β_n²², the BSDF multiplying s by √(π/8) itself. They are written
  as values, computed here, with our R-roughness scale on roughness_R's v: MaterialX 1.39.5's OSL
  implementations of `chiang_hair_roughness` and `chiang_hair_absorption_from_color` are stubs (zeros and
  vector(1)), so a document that wires those nodes renders wrongly through OSL. The BSDF clamps every v and s
  to [0.001, 1]; a lobe outside (very smooth or very rough hair) warns (LossyExportWarning).
- `absorption_coefficient` = σ_a per unit fiber radius (vector3), an albedo look inverted at β_n as
  `chiang_hair_absorption_from_color` would.
- `cuticle_angle` in [0, 1] maps to a tilt of cuticle_angle·π − π/2 radians, rotating R by +2α like ours
  (common.py): cuticle_angle = (α_rad + π/2) / π, 0.5 for no tilt. `curve_direction` must run root to tip.
- `ior` = η; the tints stay white.
- One look for every strand, root to tip: a look's variation (color_spread, roughness_spread, tip_absorption,
  tip_length; model/variation.py) is dropped with a LossyExportWarning (`NO_VARIATION`); the Cycles export
  keeps it.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from ..model.params import HairParams, logistic_polynomial, longitudinal_polynomial
from .common import NO_VARIATION, declared, fmt, lossy, roughness, sigma_a, tilt_degrees, warn_unwritten, writes

NAME = "materialx"
SUFFIX = ".mtlx"
MATERIALX_VERSION = "1.39"
# mx_chiang_hair_bsdf clamps each lobe's (v, s) to this interval.
ROUGHNESS_CLAMP = (0.001, 1.0)
# chiang_hair_roughness's default scale_TT and scale_TRT (Marschner et al. 2003), applied to v squared.
LOBE_SCALES = {"R": 1.0, "TT": 0.5, "TRT": 2.0}
_LOBES = tuple(f"roughness_{lobe}" for lobe in LOBE_SCALES)
# What chiang_hair_bsdf gets of each control (common.py, `declared`); the docstring above says how.
WRITES = declared(
    NAME,
    {
        "albedo": writes("absorption_coefficient", note="the talk's inversion at β_n"),
        "sigma_a": writes("absorption_coefficient"),
        "eumelanin": writes("absorption_coefficient", note="d'Eon's coefficients"),
        "pheomelanin": writes("absorption_coefficient", note="d'Eon's coefficients"),
        "beta_m": writes(*_LOBES, note="each lobe's v, clamped by MaterialX with a warning"),
        "beta_n": writes(*_LOBES, note="each lobe's s, clamped by MaterialX with a warning"),
        "alpha": writes("cuticle_angle", note="(α + π/2) / π with α in radians"),
        "eta": writes("ior"),
        "r_roughness_scale": writes("roughness_R", note="its v, clamped by MaterialX with a warning"),
        **NO_VARIATION,
    },
)


def lobe_roughness(params: HairParams) -> dict:
    """{"R": (v, s), "TT": ..., "TRT": ...} as chiang_hair_bsdf takes them (s without √(π/8))."""
    beta_m, beta_n = roughness(params)
    v = longitudinal_polynomial(beta_m) ** 2
    s = logistic_polynomial(beta_n)
    lobes = {name: (v * scale**2, s) for name, scale in LOBE_SCALES.items()}
    lobes["R"] = (v * params.r_roughness_scale, s)
    lo, hi = ROUGHNESS_CLAMP
    for name, (lv, ls) in lobes.items():
        for what, x in (("longitudinal variance", lv), ("logistic scale", ls)):
            if not lo <= x <= hi:
                lossy(
                    NAME,
                    f"the {name} lobe's {what} {x:.4g} is outside chiang_hair_bsdf's clamp [{lo:g}, {hi:g}]; "
                    f"MaterialX renders {min(max(x, lo), hi):g}",
                )
    return lobes


def cuticle_angle(params: HairParams) -> float:
    return (math.radians(tilt_degrees(params, NAME)) + 0.5 * math.pi) / math.pi


def _input(parent, name, type_, value):
    text = ", ".join(fmt(v) for v in value) if isinstance(value, (list, tuple)) else fmt(value)
    ET.SubElement(parent, "input", name=name, type=type_, value=text)


def document_text(params: HairParams, name: str = "warp_hair_look") -> str:
    """The .mtlx document: chiang_hair_bsdf → surface → surfacematerial `name`."""
    warn_unwritten(params, NAME, WRITES)
    root = ET.Element("materialx", version=MATERIALX_VERSION)
    root.append(ET.Comment(f" warp-hair look; controls: {params.to_dict()} "))
    bsdf = ET.SubElement(root, "chiang_hair_bsdf", name=f"{name}_bsdf", type="BSDF")
    _input(bsdf, "ior", "float", float(params.eta))
    for lobe, value in lobe_roughness(params).items():
        _input(bsdf, f"roughness_{lobe}", "vector2", value)
    _input(bsdf, "cuticle_angle", "float", cuticle_angle(params))
    _input(bsdf, "absorption_coefficient", "vector3", sigma_a(params))
    surface = ET.SubElement(root, "surface", name=f"{name}_surface", type="surfaceshader")
    ET.SubElement(surface, "input", name="bsdf", type="BSDF", nodename=bsdf.get("name"))
    material = ET.SubElement(root, "surfacematerial", name=name, type="material")
    ET.SubElement(material, "input", name="surfaceshader", type="surfaceshader", nodename=surface.get("name"))
    ET.indent(root, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


export_text = document_text
