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
- Hair as it grows (model/variation.py), with each strand's Random u and Intercept t as Cycles gives them (Hair
  Info; tests/test_cycles_variation.py measures both: u of the object's curve k is strand_random(S, 0)[k], t the
  vertices' arc-length fraction interpolated in the curve's parameter):
  - `Random Roughness` = roughness_spread: Cycles multiplies Roughness and Radial Roughness by 1 + 2(u − ½)·r,
    as ours, and a `COLOR` look is inverted at the strand's Radial Roughness, as ours. Its `Random` input is left
    unlinked, so it is the curve's random attribute. Where a strand's roughness falls below our floor 0.01,
    Cycles (clamp 0.001) renders it smoother, and Coat is exact at the material's β_m only: both warn.
  - color_spread and the tip: Cycles' `Random Color` acts on its own melanin coefficients only, and it has no
    root-to-tip input, so the `Absorption Coefficient` (`ABSORPTION` parametrization) is driven by Math nodes on
    Hair Info's Random and Intercept (the script's `absorption_nodes`), reproducing `strand_looks` times
    `tip_profile`: σ_a(u, t) = base · strand factor(u) · g(t), the base and factor per colour input (an albedo
    inverted at the strand's clamped β_n with the look's own `albedo_inversion`; σ_a times f; a melanin look's
    d'Eon σ_a times `melanin_factor`), g(t) = 1 + (a − 1)·clamp((t − (1 − L))/L, 0, 1). An albedo look whose
    strands' Radial Roughness leaves [0.01, 1] goes this way too (Cycles would invert the colour beyond it).
  A look without variation writes `Random Roughness` 0 and no nodes.
"""

from __future__ import annotations

import math

import numpy as np

from ..controls import BETA_FLOOR
from ..model.params import TALK_ALBEDO_INVERSION, HairParams, lobe_variances, longitudinal_polynomial
from ..model.variation import CYCLES_MELANIN_UNITS, MELANIN_CLAMP, spread_factor
from .common import declared, fmt, lossy, roughness, sigma_a, tilt_degrees, warn_unwritten, writes

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
        "color_spread": writes(
            "Absorption Coefficient", note="Math nodes on Hair Info's Random (Random Color is melanin-only)"
        ),
        "roughness_spread": writes("Random Roughness"),
        "tip_absorption": writes("Absorption Coefficient", note="Math nodes on Hair Info's Intercept"),
        "tip_length": writes("Absorption Coefficient", note="Math nodes on Hair Info's Intercept"),
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


def colour_parametrization_holds(params: HairParams) -> bool:
    """Whether Cycles' `COLOR` parametrization renders an albedo look's absorption as ours on every strand: the
    talk's inversion, at a Radial Roughness that `Random Roughness` keeps inside [0.01, 1] (Cycles inverts at the
    strand's value unclamped, ours at it clamped to [0, 1] and floored)."""
    if params.colour_input != "albedo" or params.albedo_inversion != TALK_ALBEDO_INVERSION:
        return False
    spread = params.roughness_spread
    return spread == 0.0 or (params.beta_n * (1.0 - spread) >= BETA_FLOOR and params.beta_n * (1.0 + spread) <= 1.0)


def absorption_variation(params: HairParams) -> dict | None:
    """What the script's `absorption_nodes` drive the Absorption Coefficient with: σ_a(u, t) = base · (strand's
    factor at Random u) · g(Intercept t) (module docstring); None where the look's absorption is one value for every
    strand, root to tip."""
    albedo_per_strand = params.colour_input == "albedo" and params.roughness_spread > 0.0
    if not (
        params.color_spread > 0.0
        or params.tip_absorption != 1.0
        or (albedo_per_strand and not colour_parametrization_holds(params))
    ):
        return None
    data = {"base": sigma_a(params), "color_spread": float(params.color_spread)}
    if albedo_per_strand:
        # (ln c)², over P(β_n·f_r clamped to [0.01, 1])² per strand.
        data["base"] = [float(np.log(c) ** 2) for c in params.albedo]
        data["radial_roughness"] = float(params.beta_n)
        data["roughness_spread"] = float(params.roughness_spread)
        data["albedo_inversion"] = [float(p) for p in params.albedo_inversion]
    if params.colour_input == "melanin" and params.color_spread > 0.0:
        units_eu, units_pheo = CYCLES_MELANIN_UNITS
        total = params.eumelanin / units_eu + params.pheomelanin / units_pheo
        if total > 0.0:  # without melanin σ_a is 0 whatever the factor
            data["melanin"] = float(total)
    data["tip_absorption"] = float(params.tip_absorption)
    data["tip_length"] = float(params.tip_length)
    return data


def _warn_roughness_spread(params: HairParams, beta_m: float, beta_n: float, coat: float) -> None:
    """Where Cycles' Random Roughness renders strands otherwise than ours: below our floor, and through Coat."""
    spread = params.roughness_spread
    if spread == 0.0:
        return
    for name, written in (("β_m", beta_m), ("β_n", beta_n)):
        if written * (1.0 - spread) < BETA_FLOOR:
            lossy(
                NAME,
                f"roughness_spread = {spread:g} takes some strands' {name} to {written * (1.0 - spread):.4g}, below "
                f"warp-hair's floor {BETA_FLOOR:g}, which Cycles does not apply (it clamps at "
                f"{ROUGHNESS_CLAMP[0]:g}): those strands render smoother there",
            )
    if coat > 0.0:
        # Coat makes R's roughness (1 − Coat)·β_m of each strand's β_m; ours scales each strand's R variance.
        lo, hi = ROUGHNESS_CLAMP
        factor = spread_factor(np.linspace(0.0, 1.0, 201), spread)
        ours = lobe_variances(np.clip(params.beta_m * factor, 0.0, 1.0), params.r_roughness_scale)[0]
        cycles_r = np.clip((1.0 - coat) * np.clip(beta_m * factor, lo, hi), lo, hi)
        error = float(np.max(np.abs(longitudinal_polynomial(cycles_r) ** 2 / ours - 1.0)))
        if error > 1e-6:
            lossy(
                NAME,
                f"Coat gives the R lobe r_roughness_scale = {params.r_roughness_scale:g} times the variance at the "
                f"material's β_m only: with roughness_spread = {spread:g} a strand's R variance is off by up to "
                f"{error:.2%}",
            )


def node_settings(params: HairParams) -> dict:
    """{"parametrization": ..., "inputs": {socket name: value}} of the Principled Hair BSDF (model CHIANG), and
    "absorption" (`absorption_variation`) where Math nodes drive its Absorption Coefficient."""
    warn_unwritten(params, NAME, WRITES)
    beta_m, beta_n = roughness(params)
    inputs = {}
    absorption = absorption_variation(params)
    if absorption is not None:
        parametrization = "ABSORPTION"  # its Absorption Coefficient is linked to `absorption_nodes`
    elif colour_parametrization_holds(params):
        parametrization = "COLOR"
        inputs["Color"] = [float(c) for c in params.albedo] + [1.0]
    else:
        parametrization = "ABSORPTION"
        inputs["Absorption Coefficient"] = sigma_a(params)
    coat = coat_from_r_roughness_scale(beta_m, params.r_roughness_scale)
    _warn_roughness_spread(params, beta_m, beta_n, coat)
    inputs.update(
        {
            "Roughness": beta_m,
            "Radial Roughness": beta_n,
            "Coat": coat,
            "IOR": float(params.eta),
            "Offset": math.radians(tilt_degrees(params, NAME)),
            "Random Roughness": float(params.roughness_spread),
        }
    )
    settings = {"model": "CHIANG", "parametrization": parametrization, "inputs": inputs}
    if absorption is not None:
        settings["absorption"] = absorption
    return settings


_SCRIPT = '''"""A warp-hair look as a Blender Cycles Principled Hair BSDF (Chiang model), made by `warp-hair export`.

Controls: {controls}
Run in Blender (Text Editor, or `blender --python THIS_FILE`): makes the material "{material}" and gives it to the
active object if it takes materials. `make_material(name)` makes it from other scripts.{variation_doc}
"""

import bpy

MODEL = "{model}"
PARAMETRIZATION = "{parametrization}"
INPUTS = {{
{inputs}
}}
{absorption_data}

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
{absorption_call}    return material


{absorption_function}if __name__ == "__main__":
    material = make_material()
    target = bpy.context.view_layer.objects.active if bpy.context.view_layer else None
    if target is not None and hasattr(target.data, "materials"):
        target.data.materials.append(material)
    print(f"made material {{material.name!r}}" + (f" on {{target.name!r}}" if target is not None else ""))
'''


_VARIATION_DOC = """
Each strand varies as warp-hair renders it, by its Hair Info Random u and Intercept t: its roughness through
Random Roughness, its absorption through the Math nodes of `absorption_nodes`."""

_ABSORPTION_DATA = """
# The Absorption Coefficient at a strand's Random u and Intercept t: base · (strand's factor at u) · (tip's at t).
ABSORPTION = {{
{entries}
}}
"""

_ABSORPTION_FUNCTION = '''def absorption_nodes(material, hair):
    """Link the hair's Absorption Coefficient to Math nodes that vary it as warp-hair does (ABSORPTION)."""
    from math import e, exp

    nodes, links = material.node_tree.nodes, material.node_tree.links
    a = ABSORPTION
    info = nodes.new("ShaderNodeHairInfo")
    u, t = info.outputs["Random"], info.outputs["Intercept"]

    def connect(x, socket):
        if isinstance(x, float):
            socket.default_value = x
        else:
            links.new(x, socket)

    def value(operation, *inputs, clamp=False):
        """A Math node's output: `operation` of the inputs (numbers, or other nodes' outputs); `clamp`: to [0, 1]."""
        node = nodes.new("ShaderNodeMath")
        node.operation = operation
        node.use_clamp = clamp
        for x, socket in zip(inputs, node.inputs):
            connect(x, socket)
        return node.outputs["Value"]

    factor = 1.0
    if a["color_spread"] > 0.0:
        factor = value("MULTIPLY_ADD", value("SUBTRACT", u, 0.5), 2.0 * a["color_spread"], 1.0)  # 1 + 2(u - 1/2) c
        if "melanin" in a:
            # As Cycles' Random Color, on the perceptual melanin m = 1 - exp(-M): -ln(max(1 - f m, {melanin_clamp})) / M
            m = 1.0 - exp(-a["melanin"])
            inside = value("MAXIMUM", value("MULTIPLY_ADD", factor, -m, 1.0), {melanin_clamp})
            factor = value("MULTIPLY", value("LOGARITHM", inside, e), -1.0 / a["melanin"])
    if "albedo_inversion" in a:
        # The albedo inverted at the strand's b = clamp(beta_n (1 + 2(u - 1/2) r), {floor}, 1): 1 / P(b)^2
        beta_n, spread = a["radial_roughness"], a["roughness_spread"]
        b = value("MULTIPLY_ADD", value("SUBTRACT", u, 0.5), 2.0 * spread * beta_n, beta_n)
        b = value("MINIMUM", value("MAXIMUM", b, {floor}), 1.0)
        p = a["albedo_inversion"][-1]
        for coefficient in reversed(a["albedo_inversion"][:-1]):
            p = value("MULTIPLY_ADD", p, b, coefficient)
        factor = value("DIVIDE", factor, value("MULTIPLY", p, p))
    if a["tip_absorption"] != 1.0:
        # g(t) = 1 + (tip_absorption - 1) clamp((t - (1 - L)) / L, 0, 1), L = tip_length
        ramp = value("MULTIPLY_ADD", t, 1.0 / a["tip_length"], 1.0 - 1.0 / a["tip_length"], clamp=True)
        factor = value("MULTIPLY", factor, value("MULTIPLY_ADD", ramp, a["tip_absorption"] - 1.0, 1.0))
    scale = nodes.new("ShaderNodeVectorMath")
    scale.operation = "SCALE"
    scale.inputs["Vector"].default_value = a["base"]
    connect(factor, scale.inputs["Scale"])
    links.new(scale.outputs["Vector"], hair.inputs["Absorption Coefficient"])


'''


def _literal(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(fmt(v) for v in value) + ")"
    return fmt(value)


def script_text(params: HairParams) -> str:
    settings = node_settings(params)
    inputs = "\n".join(f"    {name!r}: {_literal(v)}," for name, v in settings["inputs"].items())
    absorption = settings.get("absorption")
    pieces = {"variation_doc": "", "absorption_data": "", "absorption_call": "", "absorption_function": ""}
    if absorption is not None:
        entries = "\n".join(f"    {name!r}: {_literal(v)}," for name, v in absorption.items())
        pieces = {
            "variation_doc": _VARIATION_DOC,
            "absorption_data": _ABSORPTION_DATA.format(entries=entries),
            "absorption_call": "    absorption_nodes(material, hair)\n",
            "absorption_function": _ABSORPTION_FUNCTION.format(floor=fmt(BETA_FLOOR), melanin_clamp=fmt(MELANIN_CLAMP)),
        }
    return _SCRIPT.format(
        controls=params.to_dict(),
        material=MATERIAL_NAME,
        model=settings["model"],
        parametrization=settings["parametrization"],
        inputs=inputs,
        **pieces,
    )


export_text = script_text
