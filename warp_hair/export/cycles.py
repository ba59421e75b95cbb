"""Blender Cycles: the look as a runnable `bpy` script that builds a Principled Hair BSDF (Chiang model).

    warp-hair export params.json --to cycles -o hair_cycles.py
    blender --background scene.blend --python hair_cycles.py     # or run it in Blender's Text Editor

The script makes a material "warp-hair look" (`make_material(name)`) and, when run, gives it to the active
object if that object takes materials.

Conversion (Blender 4.5 intern/cycles/kernel: svm/closure.h `svm_node_closure_bsdf`, the Principled Hair case;
closure/bsdf_principled_hair_chiang.h `bsdf_hair_chiang_setup`, `hair_alpha_angles`; closure/bsdf_util.h
`bsdf_principled_hair_sigma_from_reflectance`; the bpy 4.5 wheel ships this source), checked with bpy 4.5 LTS
renders (benchmarks/vs_peers.py, which renders the exported script):
- Colour: an albedo look uses the `COLOR` parametrization (Cycles inverts the colour with the talk's polynomial at
  `Radial Roughness`, which is ours, unless the look carries a calibrated `albedo_inversion`: then, like σ_a and
  melanin looks, it uses `ABSORPTION` with our σ_a), which is per unit
  fiber radius, as Cycles'. (Cycles' own melanin coefficients are not d'Eon's, so melanin is not mapped to its
  `MELANIN` inputs.)
- `Roughness`, `Radial Roughness` = β_m, β_n: Cycles clamps them to [0.001, 1] and applies the talk's
  mappings, with √(π/8) on the logistic scale. Ours floors at 0.01, so the floored values are written.
- `Coat` from our R-roughness scale k: Cycles renders R with the *roughness* (1 − Coat)·β_m (clamped to
  [0.001, 1]) where ours multiplies the R lobe's *variance* v(β_m) by k. So Coat = 1 − β_R/β_m with
  v(β_R) = k·v(β_m). Coat lives in [0, 1]: k > 1 cannot be expressed (Coat 0, R as rough as β_m), nor a β_R
  below Cycles' 0.001 clamp; both warn (LossyExportWarning).
- `IOR` = η. `Offset` = α in radians: `bsdf_hair_chiang_setup` negates it and `hair_alpha_angles` rotates the
  viewer's θ by −2·(−Offset) for R, so positive Offset moves R toward a strand's first point, as ours (common.py).
- `Random Roughness` = 0: the look has no per-strand randomness (`Random Color` acts on melanin only).
"""

from __future__ import annotations

import math

from ..model.params import TALK_ALBEDO_INVERSION, HairParams, longitudinal_polynomial
from .common import NO_VARIATION, declared, fmt, lossy, roughness, sigma_a, tilt_degrees, warn_unwritten, writes

NAME = "cycles"
SUFFIX = ".py"
# bsdf_hair_chiang_setup clamps roughness (and the R lobe's (1 - coat) * roughness) to this interval.
ROUGHNESS_CLAMP = (0.001, 1.0)
MATERIAL_NAME = "warp-hair look"
# What the Principled Hair BSDF gets of each control (common.py, `declared`); the docstring above says how.
WRITES = declared(
    NAME,
    {
        "albedo": writes("Color", "Absorption Coefficient", note="Color, or σ_a for a calibrated albedo inversion"),
        "sigma_a": writes("Absorption Coefficient"),
        "eumelanin": writes("Absorption Coefficient", note="d'Eon's coefficients, not Cycles' Melanin"),
        "pheomelanin": writes("Absorption Coefficient", note="d'Eon's coefficients, not Cycles' Melanin"),
        "beta_m": writes("Roughness"),
        "beta_n": writes("Radial Roughness"),
        "alpha": writes("Offset", note="α in radians"),
        "eta": writes("IOR"),
        "r_roughness_scale": writes("Coat", note="only ≤ 1 and above Cycles' clamp, else a warning"),
        **NO_VARIATION,
    },
)


def coat_from_r_roughness_scale(beta_m: float, scale: float) -> float:
    """Cycles' Coat that gives the R lobe the variance scale·v(β_m); clamped to what Coat can express (warns)."""
    lo, hi = ROUGHNESS_CLAMP
    beta_m = min(max(beta_m, lo), hi)
    if scale == 1.0:
        return 0.0
    if scale > 1.0:
        lossy(
            NAME,
            f"Coat can only make the R lobe smoother: r_roughness_scale = {scale:g} > 1 becomes Coat 0 "
            "(R as rough as β_m)",
        )
        return 0.0
    target = math.sqrt(scale) * longitudinal_polynomial(beta_m)
    if target <= longitudinal_polynomial(lo):
        coat = 1.0 - lo / beta_m
        lossy(
            NAME,
            f"r_roughness_scale = {scale:g} asks for an R roughness below Cycles' clamp {lo:g}; "
            f"Coat {coat:.6g} renders the clamp",
        )
        return coat
    # poly is increasing on [0, 1]: bisect for β_R with poly(β_R) = target.
    a, b = lo, beta_m
    for _ in range(80):
        mid = 0.5 * (a + b)
        a, b = (mid, b) if longitudinal_polynomial(mid) < target else (a, mid)
    return 1.0 - 0.5 * (a + b) / beta_m


def node_settings(params: HairParams) -> dict:
    """{"parametrization": ..., "inputs": {socket name: value}} of the Principled Hair BSDF (model CHIANG)."""
    warn_unwritten(params, NAME, WRITES)
    beta_m, beta_n = roughness(params)
    inputs = {}
    if params.colour_input == "albedo" and params.albedo_inversion == TALK_ALBEDO_INVERSION:
        parametrization = "COLOR"
        inputs["Color"] = [float(c) for c in params.albedo] + [1.0]
    else:
        parametrization = "ABSORPTION"
        inputs["Absorption Coefficient"] = sigma_a(params)
    inputs.update(
        {
            "Roughness": beta_m,
            "Radial Roughness": beta_n,
            "Coat": coat_from_r_roughness_scale(beta_m, params.r_roughness_scale),
            "IOR": float(params.eta),
            "Offset": math.radians(tilt_degrees(params, NAME)),
            "Random Roughness": 0.0,
        }
    )
    return {"model": "CHIANG", "parametrization": parametrization, "inputs": inputs}


_SCRIPT = '''"""A warp-hair look as a Blender Cycles Principled Hair BSDF (Chiang model), made by `warp-hair export`.

Controls: {controls}
Run in Blender (Text Editor, or `blender --python THIS_FILE`): makes the material "{material}" and gives it to the
active object if it takes materials. `make_material(name)` makes it from other scripts.
"""

import bpy

MODEL = "{model}"
PARAMETRIZATION = "{parametrization}"
INPUTS = {{
{inputs}
}}


def make_material(name="{material}"):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    hair.model = MODEL
    hair.parametrization = PARAMETRIZATION
    for socket, value in INPUTS.items():
        hair.inputs[socket].default_value = value
    output = nodes.new("ShaderNodeOutputMaterial")
    output.target = "CYCLES"
    links.new(hair.outputs["BSDF"], output.inputs["Surface"])
    return material


if __name__ == "__main__":
    material = make_material()
    target = bpy.context.view_layer.objects.active if bpy.context.view_layer else None
    if target is not None and hasattr(target.data, "materials"):
        target.data.materials.append(material)
    print(f"made material {{material.name!r}}" + (f" on {{target.name!r}}" if target is not None else ""))
'''


def _literal(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(fmt(v) for v in value) + ")"
    return fmt(value)


def script_text(params: HairParams) -> str:
    settings = node_settings(params)
    inputs = "\n".join(f"    {name!r}: {_literal(v)}," for name, v in settings["inputs"].items())
    return _SCRIPT.format(
        controls=params.to_dict(),
        material=MATERIAL_NAME,
        model=settings["model"],
        parametrization=settings["parametrization"],
        inputs=inputs,
    )


export_text = script_text
