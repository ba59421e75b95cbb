"""Exports to Mitsuba 3, pbrt-v4, Blender Cycles and MaterialX, checked against each renderer's own formulas.

Every renderer's conversion is undone here with the formulas of that renderer's source (named in each test),
written independently of warp_hair.export; the tilt sign is checked from where each renderer's R lobe peaks.
"""

import json
import math
import re
import subprocess
import sys
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from scipy.special import i0e

from warp_hair.cli import main
from warp_hair.controls import CONTROL_NAMES, CONTROLS, controls_of
from warp_hair.export import RENDERERS, LossyExportWarning, controls_table, export, load_look
from warp_hair.export.common import NO_VARIATION, Cannot, declared, warn_unwritten
from warp_hair.export.cycles import coat_from_r_roughness_scale, node_settings
from warp_hair.model.params import HairParams, lobe_variances, logistic_scale
from warp_hair.model.variation import strand_looks, strand_random, tip_profile

LOOKS = {
    "albedo": HairParams(albedo=(0.6, 0.4, 0.2), beta_m=0.25, beta_n=0.4, alpha=2.5, eta=1.6),
    "sigma_a": HairParams(sigma_a=(0.5, 1.0, 2.0), beta_m=0.35, beta_n=0.3, alpha=-3.0, eta=1.5),
    "melanin": HairParams(eumelanin=1.3, pheomelanin=0.2, beta_m=0.3, beta_n=0.3, alpha=2.0),
}
D_EON_EU, D_EON_PHEO = np.array([0.419, 0.697, 1.37]), np.array([0.187, 0.4, 1.05])


def chiang_denominator(b):
    """The talk's albedo polynomial, as pbrt-v4 SigmaAFromReflectance and Cycles write it (Horner's form)."""
    return (((((0.245 * b) + 5.574) * b - 10.73) * b + 2.532) * b - 0.215) * b + 5.969


def expected_sigma_a(params):
    if params.colour_input == "albedo":
        return (np.log(params.albedo) / chiang_denominator(max(params.beta_n, 0.01))) ** 2
    if params.colour_input == "sigma_a":
        return np.array(params.sigma_a)
    return params.eumelanin * D_EON_EU + params.pheomelanin * D_EON_PHEO


def v_of(beta):
    return (0.726 * beta + 0.812 * beta**2 + 3.7 * beta**20) ** 2


def log_m_p(sin_a, cos_a, sin_b, cos_b, v):
    """log of d'Eon et al.'s longitudinal lobe up to a constant (every renderer evaluates this function)."""
    x = cos_a * cos_b / v
    return np.log(i0e(x)) + x - sin_a * sin_b / v


def r_peak(rotate, theta_o, v=1e-4):
    """θ_i where a renderer's R lobe peaks for a viewer at θ_o; `rotate(θ_i, θ_o)` → the pair M is evaluated at."""
    theta_i = np.linspace(-1.2, 1.2, 240001)
    a, b = rotate(theta_i, theta_o)
    return theta_i[np.argmax(log_m_p(np.sin(a), np.cos(a), np.sin(b), np.cos(b), v))]


def assert_r_toward_root(rotate, alpha_deg):
    """With θ positive toward the tip, physical scales put R at θ_i + θ_o = −2α (toward the root)."""
    for theta_o in (-0.4, 0.0, 0.3):
        assert r_peak(rotate, theta_o) + theta_o == pytest.approx(-2 * math.radians(alpha_deg), abs=5e-5)


# --- Mitsuba 3 (src/bsdfs/hair.cpp) ------------------------------------------------------------------------


def mitsuba_element(params):
    root = ET.fromstring(export(params, "mitsuba"))
    assert root.tag == "bsdf" and root.get("type") == "hair" and root.get("version")
    floats = {e.get("name"): float(e.get("value")) for e in root.findall("float")}
    (rgb,) = root.findall("rgb")
    assert rgb.get("name") == "sigma_a"
    return floats, np.array([float(c) for c in rgb.get("value").split(",")])


@pytest.mark.parametrize("colour", LOOKS)
def test_mitsuba_values(colour):
    params = LOOKS[colour]
    floats, sigma = mitsuba_element(params)
    # Mitsuba has no albedo input: the talk's inversion, undone, gives the fitted albedo back.
    np.testing.assert_allclose(sigma, expected_sigma_a(params), rtol=1e-12)
    if params.albedo is not None:
        np.testing.assert_allclose(
            np.exp(-np.sqrt(sigma) * chiang_denominator(params.beta_n)), params.albedo, rtol=1e-12
        )
    assert floats["longitudinal_roughness"] == params.beta_m and floats["azimuthal_roughness"] == params.beta_n
    # Hair(): m_eta = int_ior / ext_ior.
    assert floats["int_ior"] / floats["ext_ior"] == pytest.approx(params.eta, rel=1e-15)
    assert_r_toward_root(mitsuba_rotation(floats["scale_tilt"]), params.alpha)


def mitsuba_rotation(scale_tilt_deg):
    """reframe_with_scales, case 0: the viewer direction (Mitsuba's wi) rotated by −2·scale_tilt."""
    two_alpha = 2 * math.radians(scale_tilt_deg)
    return lambda theta_i, theta_o: (theta_i, theta_o - two_alpha)


def test_mitsuba_floors_roughness_and_warns_on_r_scale():
    with pytest.warns(UserWarning, match="below 0.01"):
        params = HairParams(albedo=0.5, beta_m=0.004, r_roughness_scale=2.0)
    with pytest.warns(LossyExportWarning, match="r_roughness_scale = 2"):
        floats, _ = mitsuba_element(params)
    assert floats["longitudinal_roughness"] == 0.01  # ours renders the floor; Mitsuba does not clamp
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mitsuba_element(LOOKS["albedo"])


def test_mitsuba_loads_the_export(tmp_path):
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is the `bench` extra")
    mi.set_variant("scalar_rgb")
    params = LOOKS["albedo"]
    out = tmp_path / "hair.xml"
    assert main(["export", "--to", "mitsuba", "-o", str(out), str(write_look(tmp_path, params))]) == 0
    values = mi.traverse(mi.load_string(out.read_text()))
    np.testing.assert_allclose(np.ravel(values["sigma_a.value"]), expected_sigma_a(params), rtol=1e-6)
    assert values["eta"] == pytest.approx(params.eta, rel=1e-6)
    assert values["scale_tilt"] == pytest.approx(-params.alpha)


# --- pbrt-v4 (src/pbrt/materials.cpp HairMaterial::Create, materials.h GetBxDF, bxdfs.cpp HairBxDF) ------


def pbrt_parameters(text):
    assert re.search(r'^Material "hair"$', text, re.M)
    return {m[1]: [float(x) for x in m[2].split()] for m in re.finditer(r'"(\w+ \w+)" \[ ([^\]]*) \]', text)}


@pytest.mark.parametrize("colour", LOOKS)
def test_pbrt_values(colour):
    params = LOOKS[colour]
    values = pbrt_parameters(export(params, "pbrt"))
    assert set(values) == {"rgb sigma_a", "float beta_m", "float beta_n", "float alpha", "float eta"}
    np.testing.assert_allclose(values["rgb sigma_a"], expected_sigma_a(params), rtol=1e-12)
    assert values["float beta_m"] == [params.beta_m] and values["float beta_n"] == [params.beta_n]
    assert values["float eta"] == [params.eta]
    # HairBxDF::f, p = 0: sinThetap_o = sinTheta_o cos 2α − cosTheta_o sin 2α (α in degrees).
    two_alpha = 2 * math.radians(values["float alpha"][0])
    assert_r_toward_root(lambda ti, to: (ti, to - two_alpha), params.alpha)


# --- Blender Cycles (svm/closure.h, closure/bsdf_principled_hair_chiang.h) --------------------------------


def cycles_r_variance(roughness, coat):
    """bsdf_hair_chiang_setup: m0 = clamp((1 − clamp(coat, 0, 1)) · clamp(roughness), 0.001, 1), v_R = v(m0)."""
    v = min(max(roughness, 0.001), 1.0)
    return v_of(min(max((1.0 - min(max(coat, 0.0), 1.0)) * v, 0.001), 1.0))


@pytest.mark.parametrize("colour", LOOKS)
def test_cycles_values(colour):
    params = LOOKS[colour]
    settings = node_settings(params)
    inputs = settings["inputs"]
    assert settings["model"] == "CHIANG"
    if colour == "albedo":
        assert settings["parametrization"] == "COLOR"
        # bsdf_principled_hair_sigma_from_reflectance at Radial Roughness.
        sigma = (np.log(inputs["Color"][:3]) / chiang_denominator(inputs["Radial Roughness"])) ** 2
    else:
        assert settings["parametrization"] == "ABSORPTION"
        sigma = np.array(inputs["Absorption Coefficient"])
    np.testing.assert_allclose(sigma, expected_sigma_a(params), rtol=1e-12)
    assert inputs["Roughness"] == params.beta_m and inputs["Radial Roughness"] == params.beta_n
    assert inputs["IOR"] == params.eta and inputs["Coat"] == 0.0
    # The logistic scale: (0.265 s + 1.194 s² + 5.372 s²²) · √(π/8), as ours.
    s = inputs["Radial Roughness"]
    assert (0.265 * s + 1.194 * s**2 + 5.372 * s**22) * math.sqrt(math.pi / 8) == pytest.approx(
        logistic_scale(params.beta_n)
    )
    # Blender 4.5: bsdf_hair_chiang_setup sets alpha = −Offset (radians) and hair_alpha_angles evaluates R at
    # the viewer's sin θ_o cos 2α − cos θ_o sin 2α.
    two_alpha = 2 * -inputs["Offset"]
    assert_r_toward_root(lambda ti, to: (ti, to - two_alpha), params.alpha)


def test_cycles_takes_a_calibrated_inversion_as_absorption():
    """Cycles inverts a colour with the talk's polynomial: a look with its own inversion goes as σ_a."""
    params = HairParams(albedo=[0.6, 0.4, 0.2], beta_n=0.4, albedo_inversion=(5.0, 0.1, 1.0, -4.0, 2.0, 0.3))
    settings = node_settings(params)
    assert settings["parametrization"] == "ABSORPTION"
    expected = (np.log([0.6, 0.4, 0.2]) / np.polyval([0.3, 2.0, -4.0, 1.0, 0.1, 5.0], 0.4)) ** 2
    np.testing.assert_allclose(settings["inputs"]["Absorption Coefficient"], expected, rtol=1e-12)


@pytest.mark.parametrize("beta_m", [0.1, 0.3, 0.7])
@pytest.mark.parametrize("scale", [0.1, 0.5, 0.9, 1.0])
def test_cycles_coat_gives_our_r_variance(beta_m, scale):
    coat = coat_from_r_roughness_scale(beta_m, scale)
    assert 0.0 <= coat < 1.0
    ours = lobe_variances(beta_m, scale)[0]
    assert cycles_r_variance(beta_m, coat) == pytest.approx(ours, rel=1e-9)


def test_cycles_coat_clamps_with_a_warning():
    with pytest.warns(LossyExportWarning, match="Coat 0"):
        assert coat_from_r_roughness_scale(0.3, 1.5) == 0.0
    with pytest.warns(LossyExportWarning, match="below Cycles' clamp"):
        coat = coat_from_r_roughness_scale(0.3, 1e-8)
    assert cycles_r_variance(0.3, coat) == pytest.approx(v_of(0.001))


def test_cycles_script_is_python_with_the_settings():
    params = HairParams(albedo=(0.6, 0.4, 0.2), r_roughness_scale=0.5)
    text = export(params, "cycles")
    namespace = {}
    compile(text, "hair_cycles.py", "exec")
    body = text.split("def make_material")[0].replace("import bpy", "")
    exec(body, namespace)
    settings = node_settings(params)
    assert namespace["PARAMETRIZATION"] == settings["parametrization"]
    assert namespace["INPUTS"] == {k: tuple(v) if isinstance(v, list) else v for k, v in settings["inputs"].items()}


@pytest.mark.bpy
def test_cycles_script_builds_the_node_in_blender(tmp_path):
    """Opt-in (`pytest -m bpy`): runs the script in Blender's Python module and reads the node back."""
    pytest.importorskip("bpy", reason="bpy 4.5 (Python 3.11) is the `blender` extra")
    params = HairParams(sigma_a=(0.5, 1.0, 2.0), r_roughness_scale=0.5, alpha=2.0)
    script = tmp_path / "hair_cycles.py"
    export(params, "cycles", script)
    probe = (
        f"import runpy; m = runpy.run_path({str(script)!r})['make_material']()\n"
        "n = [n for n in m.node_tree.nodes if n.bl_idname == 'ShaderNodeBsdfHairPrincipled'][0]\n"
        "print(n.model, n.parametrization, [round(x, 6) for x in n.inputs['Absorption Coefficient'].default_value],"
        " round(n.inputs['Coat'].default_value, 6), round(n.inputs['Offset'].default_value, 6))\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, check=True).stdout
    coat = coat_from_r_roughness_scale(0.3, 0.5)
    assert f"CHIANG ABSORPTION [0.5, 1.0, 2.0] {round(coat, 6)} {round(math.radians(2.0), 6)}" in out


# --- Cycles: hair as it grows (svm/closure.h Principled Hair; svm/math_util.h, util/math_base.h for Math nodes) --

# Blender 4.5's node sockets, by position, of the nodes the script makes (the hair's and the output's by name).
SOCKETS = {
    "ShaderNodeMath": (["Value"] * 3, ["Value"]),
    "ShaderNodeVectorMath": (["Vector", "Vector", "Vector", "Scale"], ["Vector", "Value"]),
    "ShaderNodeHairInfo": ([], ["Is Strand", "Intercept", "Length", "Thickness", "Tangent Normal", "Random"]),
}
# Cycles' Math operations (svm/math_util.h svm_math): safe_divide and safe_logf give 0 where undefined.
MATH = {
    "SUBTRACT": lambda a, b, c: a - b,
    "MULTIPLY": lambda a, b, c: a * b,
    "DIVIDE": lambda a, b, c: np.where(b != 0.0, a / np.where(b != 0.0, b, 1.0), 0.0),
    "MINIMUM": lambda a, b, c: np.fmin(a, b),
    "MAXIMUM": lambda a, b, c: np.fmax(a, b),
    "MULTIPLY_ADD": lambda a, b, c: a * b + c,
    "LOGARITHM": lambda a, b, c: np.where(
        (a > 0.0) & (b > 0.0), np.log(np.where(a > 0.0, a, 1.0)) / np.log(np.where(b > 0.0, b, 2.0)), 0.0
    ),
}


class Socket:
    def __init__(self, node, name):
        self.node, self.name, self.default_value, self.link = node, name, 0.0, None


class Sockets(list):
    """A node's sockets: by position, or by name (the first of that name, as bpy), made on first use where the
    node's sockets are not listed in SOCKETS."""

    def __init__(self, node, names, open_ended):
        super().__init__(Socket(node, name) for name in names)
        self.node, self.open_ended = node, open_ended

    def __getitem__(self, key):
        if isinstance(key, int):
            return super().__getitem__(key)
        for socket in self:
            if socket.name == key:
                return socket
        assert self.open_ended, f"{self.node.kind} has no socket {key!r}"
        self.append(Socket(self.node, key))
        return self[-1]


class Node:
    def __init__(self, kind):
        self.kind, self.operation, self.use_clamp = kind, None, False
        inputs, outputs = SOCKETS.get(kind, ([], []))
        self.inputs = Sockets(self, inputs, kind not in SOCKETS)
        self.outputs = Sockets(self, outputs, kind not in SOCKETS)


class NodeTree:
    def __init__(self):
        self.nodes = type("Nodes", (list,), {"new": lambda nodes, kind: nodes.append(Node(kind)) or nodes[-1]})()
        self.links = type("Links", (), {"new": lambda links, out, to: setattr(to, "link", out)})()


def run_cycles_script(text):
    """The exported script's make_material run against stand-in bpy node trees: its Principled Hair node."""
    material = type("Material", (), {"node_tree": NodeTree()})()
    bpy = type("bpy", (), {"data": type("data", (), {"materials": type("m", (), {"new": lambda name: material})})})
    namespace = {}
    exec(text.replace("import bpy", ""), namespace)
    namespace["bpy"] = bpy
    namespace["make_material"]()
    (hair,) = [n for n in material.node_tree.nodes if n.kind == "ShaderNodeBsdfHairPrincipled"]
    return hair


def evaluate(socket, u, t):
    """A socket's value as Cycles' SVM computes it, at Hair Info's Random u and Intercept t (broadcast)."""
    if socket.link is None:
        return np.asarray(socket.default_value, dtype=np.float64)
    node, name = socket.link.node, socket.link.name
    if node.kind == "ShaderNodeHairInfo":
        return {"Random": u, "Intercept": t}[name]
    a, b, c = (evaluate(s, u, t) for s in list(node.inputs)[:3])
    if node.kind == "ShaderNodeVectorMath":
        assert node.operation == "SCALE"
        return a * evaluate(node.inputs["Scale"], u, t)[..., None]
    value = MATH[node.operation](a, b, c)
    return np.clip(value, 0.0, 1.0) if node.use_clamp else value


GROWING = {
    "albedo": HairParams(
        albedo=(0.55, 0.4, 0.25), beta_n=0.35, color_spread=0.4, roughness_spread=0.25, tip_absorption=0.3
    ),
    "albedo, calibrated inversion, roughness spread only": HairParams(
        albedo=(0.6, 0.4, 0.2), beta_n=0.4, roughness_spread=0.5, albedo_inversion=(5.0, 0.1, 1.0, -4.0, 2.0, 0.3)
    ),
    "albedo, strands' β_n beyond 1": HairParams(albedo=(0.6, 0.4, 0.2), beta_n=0.9, roughness_spread=0.3),
    "albedo, strands' β_n below the floor": HairParams(albedo=(0.6, 0.4, 0.2), beta_n=0.015, roughness_spread=0.6),
    "sigma_a, short tip": HairParams(sigma_a=(0.5, 1.0, 2.0), color_spread=0.7, tip_absorption=4.0, tip_length=0.2),
    "melanin": HairParams(eumelanin=1.3, pheomelanin=0.2, color_spread=0.4, tip_absorption=0.5, tip_length=0.7),
    "melanin at Cycles' clamp": HairParams(eumelanin=8.0, pheomelanin=0.5, color_spread=1.0),
    "tip only": HairParams(albedo=0.5, beta_n=0.3, tip_absorption=0.1, tip_length=1.0),
}


@pytest.mark.parametrize("name", GROWING)
def test_cycles_absorption_nodes_are_each_strands_look(name):
    """The exported Math nodes, evaluated as Cycles does at each strand's Random and along its Intercept, are
    warp-hair's σ_a there (model/variation.py's strand_looks times tip_profile)."""
    params = GROWING[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LossyExportWarning)
        hair = run_cycles_script(export(params, "cycles"))
    assert hair.parametrization == "ABSORPTION"
    u = strand_random(200)[:, None].astype(np.float64)
    t = np.linspace(0.0, 1.0, 101)[None, :]
    got = evaluate(hair.inputs["Absorption Coefficient"], u, t)
    want = (
        strand_looks(params, u[:, 0]).sigma_a[:, None, :]
        * tip_profile(t, params.tip_absorption, params.tip_length)[..., None]
    )
    np.testing.assert_allclose(np.broadcast_to(got, want.shape), want, rtol=1e-12)
    assert np.ptp(want, axis=(0, 1)).min() > 0.0  # it does vary


@pytest.mark.parametrize("beta_n", [0.3, 0.01])
def test_cycles_random_roughness_and_colour_are_each_strands_look(beta_n):
    """An albedo look that varies only in roughness stays Cycles' COLOR parametrization: Cycles randomises
    Roughness and Radial Roughness by Random Roughness and inverts the colour at the strand's Radial Roughness
    (svm/closure.h), which is strand_looks' β and σ_a."""
    params = HairParams(albedo=(0.6, 0.4, 0.2), beta_m=0.25, beta_n=beta_n, roughness_spread=0.5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        settings = node_settings(params)
    inputs = settings["inputs"]
    u = strand_random(100).astype(np.float64)
    factor = 1.0 + 2.0 * (u - 0.5) * inputs["Random Roughness"]
    looks = strand_looks(params, u)
    np.testing.assert_allclose(inputs["Roughness"] * factor, looks.beta_m, rtol=1e-12)
    if beta_n * 0.5 >= 0.01:
        assert settings["parametrization"] == "COLOR" and "absorption" not in settings
        sigma = (
            np.log(inputs["Color"][:3])[None, :] / chiang_denominator(inputs["Radial Roughness"] * factor)[:, None]
        ) ** 2
        np.testing.assert_allclose(sigma, looks.sigma_a, rtol=1e-12)
        assert not caught
    else:  # Cycles would invert at a Radial Roughness below our floor, and render those strands smoother: warned
        assert settings["parametrization"] == "ABSORPTION" and "absorption" in settings
        assert any("below warp-hair's floor 0.01" in str(w.message) and "β_n" in str(w.message) for w in caught)


def test_cycles_warns_where_coat_meets_random_roughness():
    with pytest.warns(LossyExportWarning, match=r"R variance is off by up to \d"):
        export(HairParams(albedo=0.5, beta_m=0.3, r_roughness_scale=0.5, roughness_spread=0.3), "cycles")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        export(HairParams(albedo=0.5, beta_m=0.3, r_roughness_scale=0.5), "cycles")
        export(HairParams(albedo=0.5, beta_m=0.3, roughness_spread=0.3), "cycles")


# --- MaterialX 1.39 (pbrlib_defs.mtlx, genglsl/mx_chiang_hair_bsdf.glsl) --------------------------------


def materialx_inputs(text):
    mx = pytest.importorskip("MaterialX", reason="MaterialX is the `materialx` extra")
    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    doc.setDataLibrary(library)
    valid, message = doc.validate()
    assert valid, message
    (material,) = doc.getMaterialNodes()
    shader = material.getInput("surfaceshader").getConnectedNode()
    bsdf = shader.getInput("bsdf").getConnectedNode()
    assert bsdf.getCategory() == "chiang_hair_bsdf" and bsdf.getNodeDef().getName() == "ND_chiang_hair_bsdf"
    return {
        i.getName(): np.atleast_1d(
            np.array(list(i.getValue()) if hasattr(i.getValue(), "__len__") else i.getValue(), dtype=np.float64)
        )
        for i in bsdf.getInputs()
    }


@pytest.mark.parametrize("colour", LOOKS)
def test_materialx_document_validates_with_our_numbers(colour):
    params = LOOKS[colour].replace(r_roughness_scale=0.6)
    inputs = materialx_inputs(export(params, "materialx"))
    np.testing.assert_allclose(inputs["absorption_coefficient"], expected_sigma_a(params), rtol=1e-6)
    # chiang_hair_roughness: (v·scale², s) with scale_TT 0.5, scale_TRT 2; the BSDF multiplies s by √(π/8).
    ours = lobe_variances(params.beta_m, params.r_roughness_scale)
    for lobe, k in (("R", 0), ("TT", 1), ("TRT", 2)):
        v, s = inputs[f"roughness_{lobe}"]
        assert v == pytest.approx(ours[k], rel=1e-6)
        assert s * 0.626657 == pytest.approx(logistic_scale(params.beta_n), rel=1e-5)
    assert inputs["ior"][0] == pytest.approx(params.eta, rel=1e-6)
    # mx_chiang_hair_bsdf: alpha = cuticle_angle·π − π/2; R is evaluated at the light's θ_i rotated by +2α.
    alpha = inputs["cuticle_angle"][0] * math.pi - math.pi / 2
    assert_r_toward_root(lambda ti, to: (ti + 2 * alpha, to), params.alpha)


def test_materialx_warns_where_its_clamp_bites():
    with pytest.warns(LossyExportWarning, match="TRT lobe's longitudinal variance"):
        export(HairParams(albedo=0.5, beta_m=0.6), "materialx")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        export(HairParams(albedo=0.5, beta_m=0.3), "materialx")


# --- LOOK files and the command line ----------------------------------------------------------------------


def write_look(tmp_path, params, name="params.json"):
    path = tmp_path / name
    path.write_text(json.dumps({"target": "t", "fitted": {}, "look": params.to_dict()}))
    return path


def test_load_look_from_params_truth_and_scene(tmp_path):
    params = LOOKS["albedo"]
    assert load_look(write_look(tmp_path, params)) == params
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps(params.to_dict()))
    assert load_look(truth) == params
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[camera]\nwidth = 1\n[hair]\nalbedo = [0.6, 0.4, 0.2]\nbeta_m = 0.25\nbeta_n = 0.4\nalpha = 2.5\neta = 1.6\n"
    )
    assert load_look(scene) == params


@pytest.mark.parametrize(
    "content, message",
    [
        ('{"look": {"beta_m": 0.3}}', r"params.json \"look\": HairParams needs exactly one colour input"),
        ('{"target": "t", "fitted": {"albedo": [0.5, 0.5, 0.5]}}', 'has no "look"'),
        ('{"colour": 1}', "unknown keys \\['colour'\\]"),
        ("[1, 2]", "must be an object"),
        ("{", "not a JSON look"),
    ],
)
def test_bad_look_files_name_the_file(tmp_path, content, message):
    path = tmp_path / "params.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=message):
        load_look(path)


def test_cli_export_to_stdout_and_file(tmp_path, capsys):
    look = write_look(tmp_path, LOOKS["sigma_a"])
    assert main(["export", str(look), "--to", "pbrt"]) == 0
    assert pbrt_parameters(capsys.readouterr().out)["rgb sigma_a"] == [0.5, 1.0, 2.0]
    out = tmp_path / "hair.mtlx"
    assert main(["export", str(look), "--to", "materialx", "-o", str(out)]) == 0
    assert "chiang_hair_bsdf" in out.read_text()


@pytest.mark.parametrize(
    "args, message",
    [
        (["missing.json", "--to", "mitsuba"], "missing.json: look file not found"),
        (["LOOK", "--to", "arnold"], "unknown renderer 'arnold'"),
        (["NOCOLOUR", "--to", "cycles"], "needs exactly one colour input"),
    ],
)
def test_cli_export_errors(tmp_path, capsys, args, message):
    nocolour = tmp_path / "nocolour.json"
    nocolour.write_text('{"beta_m": 0.3}')
    swap = {
        "LOOK": str(write_look(tmp_path, LOOKS["albedo"])),
        "NOCOLOUR": str(nocolour),
        "missing.json": str(tmp_path / "missing.json"),
    }
    assert main(["export", *[swap.get(a, a) for a in args]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("warp-hair: error: ") and message in err and "Traceback" not in err


def test_cli_reports_what_a_renderer_cannot_express(tmp_path, capsys):
    look = write_look(tmp_path, HairParams(albedo=0.5, r_roughness_scale=0.5))
    assert main(["export", str(look), "--to", "mitsuba", "-o", str(tmp_path / "hair.xml")]) == 0
    err = capsys.readouterr().err
    assert "warp-hair: warning: mitsuba export: it has no R-roughness scale: r_roughness_scale = 0.5" in err


# --- What each exporter declares it writes, control by control (WRITES) --------------------------------------

ROOT = Path(__file__).resolve().parents[1]


def written(renderer, text):
    """{parameter: value as written} of an exported file, read back as the renderer's parser would see it."""
    if renderer == "mitsuba":
        return {e.get("name"): e.get("value") for e in ET.fromstring(text)}
    if renderer == "pbrt":
        return pbrt_parameters(text)
    if renderer == "cycles":
        namespace = {}
        exec(text.split("def make_material")[0].replace("import bpy", ""), namespace)
        # Math nodes drive the Absorption Coefficient of a look that varies (ABSORPTION).
        return {
            **namespace["INPUTS"],
            **({"Absorption Coefficient": namespace["ABSORPTION"]} if "ABSORPTION" in namespace else {}),
        }
    (bsdf,) = ET.fromstring(text).iter("chiang_hair_bsdf")
    return {e.get("name"): e.get("value") for e in bsdf}


def moved(params, name):
    """The look with one control moved as gradcheck moves it (a step every control's table entry gives)."""
    how, amount = CONTROLS[name].gradcheck_move
    value = np.asarray(getattr(params, name), dtype=np.float64)
    value = value * amount if how == "scale" else value + amount
    return params.replace(**{name: value.tolist()})


def test_every_exporter_declares_every_control_of_the_table():
    for module in RENDERERS.values():
        assert tuple(module.WRITES) == CONTROL_NAMES, module.NAME


def test_a_declaration_missing_or_inventing_a_control_is_refused():
    mitsuba = RENDERERS["mitsuba"].WRITES
    lacking = {name: what for name, what in mitsuba.items() if name != "r_roughness_scale"}
    with pytest.raises(ImportError, match=r"mitsuba.py declares nothing for the controls \['r_roughness_scale'\]"):
        declared("mitsuba", lacking)
    with pytest.raises(ImportError, match=r"the table does not have: \['hue'\]"):
        declared("mitsuba", dict(mitsuba, hue=mitsuba["eta"]))


def test_a_control_added_to_the_table_stops_the_exporters_import():
    """As a developer meets it: a new entry in CONTROLS, and `import warp_hair.export` names it."""
    code = (
        "import dataclasses, warp_hair.controls as c\n"
        "c.CONTROLS['hue'] = dataclasses.replace(c.CONTROLS['eta'], name='hue')\n"
        "c.CONTROL_NAMES = tuple(c.CONTROLS)\n"
        "import warp_hair.export\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode != 0
    assert re.search(r"ImportError: warp_hair/export/\w+\.py declares nothing for the controls \['hue'\]", run.stderr)


@pytest.mark.parametrize("to", RENDERERS)
def test_each_declaration_is_what_the_export_does(to):
    """A control declared written moves one of its declared parameters; one declared unwritable moves none, and
    the export warns with the declaration's reason. Every parameter declared is one the renderer is given."""
    seen = set()
    for colour, look in LOOKS.items():
        look = look.replace(r_roughness_scale=0.5)  # where Cycles' Coat and MaterialX's clamp express it
        for name in controls_of(colour):
            # The tip's length acts only where the tip's absorption differs from the root's.
            base = look.replace(tip_absorption=0.5) if name == "tip_length" else look
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LossyExportWarning)
                before = written(to, export(base, to))
            what = RENDERERS[to].WRITES[name]
            look_moved = moved(base, name)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                after = written(to, export(look_moved, to))
            seen |= set(after)
            changed = {key for key in after.keys() | before.keys() if after.get(key) != before.get(key)}
            messages = [str(w.message) for w in caught if w.category is LossyExportWarning]
            if isinstance(what, Cannot):
                assert not changed, (name, changed)
                assert any(m.startswith(f"{to} export: {what.reason}: {name} = ") for m in messages), messages
            else:
                assert changed & set(what.parameters), (colour, name, changed, what.parameters)
    declared_parameters = {
        p for what in RENDERERS[to].WRITES.values() if not isinstance(what, Cannot) for p in what.parameters
    }
    assert declared_parameters <= seen, declared_parameters - seen


def test_unwritten_controls_warn_only_when_the_look_sets_them():
    declaration = {"albedo": Cannot("it has no albedo", "σ_a of 1")}
    with pytest.warns(LossyExportWarning, match=r"^x export: it has no albedo: albedo = \(0.6, 0.4, 0.2\) is dropped"):
        warn_unwritten(LOOKS["albedo"], "x", declaration)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # not given: no albedo, and no melanin (whose default, 0, is for the other pigment's look)
        warn_unwritten(LOOKS["sigma_a"], "x", dict(declaration, eumelanin=Cannot("no melanin", "none")))
        warn_unwritten(LOOKS["albedo"], "x", {"r_roughness_scale": Cannot("no scale", "1")})  # at its default
        # a control that acts only with another, which the look leaves at its default
        warn_unwritten(LOOKS["albedo"].replace(tip_length=0.3), "x", {"tip_length": NO_VARIATION["tip_length"]})
    with pytest.warns(
        LossyExportWarning, match=r"^x export: it has no root-to-tip change: tip_length = 0.3 is dropped"
    ):
        warn_unwritten(
            LOOKS["albedo"].replace(tip_length=0.3, tip_absorption=0.5), "x", {"tip_length": NO_VARIATION["tip_length"]}
        )


def test_docs_table_is_the_declarations():
    table = controls_table()
    assert table.count("\n") == 2 + len(CONTROL_NAMES)
    assert table in (ROOT / "docs" / "export.md").read_text(encoding="utf-8"), (
        "docs/export.md's table of what each renderer writes is not warp_hair.export.controls_table(): paste it in"
    )
