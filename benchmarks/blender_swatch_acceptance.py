"""Acceptance on hair warp-hair did not make (issue 43, item 4): draped swatches whose strands Blender made, rendered
by Cycles, fitted from the recipe a photographer would write down.

    python benchmarks/blender_swatch_acceptance.py make [NAMES] [--spp 1024] [--threads 2]   # with bpy 4.5
    python benchmarks/blender_swatch_acceptance.py card [NAMES] [--spp 1024]                 # with bpy 4.5
    python benchmarks/blender_swatch_acceptance.py photo [NAMES] [--no-card]
    python benchmarks/blender_swatch_acceptance.py fit [NAMES] [--out DIR] [--threads T]
    python benchmarks/blender_swatch_acceptance.py table [--out DIR]
    python benchmarks/blender_swatch_acceptance.py compare [NAMES] [--spp 256]
    python benchmarks/error_over_sigma.py benchmarks/out/blender_swatches/fits

`make` (an environment with bpy 4.5, Python 3.11, and warp-hair's dependencies) builds each swatch in Blender as
Geometry Nodes hair curves (below), lays it over the rod, renders it with Cycles front- and back-lit
(benchmarks/cycles_peer.py: the shipped cycles_* targets' settings, camera and lights; the look as `warp-hair export
--to cycles` writes it: Principled Hair, Chiang, Direct Coloring, Random Color and Random Roughness 0) and writes
targets/blender_<name>: the two linear EXRs, scene files whose [fibers] is the recipe (what `targets photo` writes
for the same flags: jitter 0.15, seed 1, no word of Blender's seed), `realisations = "random"`, truth.json (the look
in warp-hair's controls) and blender.json (what Blender was asked for, what was measured off its strands, the
recipe's flags). The strands go to OUT/strands/<name>.hair for `compare`. `card` (bpy too) renders the front view
again with an 18% grey card in the shot (CARD: a Lambertian square above the strands in the frame's corner) into
OUT/card/<name>. The others run in warp-hair's own environment.
`photo` turns each pair of renders into what a camera saves (each view auto-exposed: its 99.5th percentile to about
0.9, the shutter on the nearest third stop at f/8 and ISO 100, recorded in EXIF as a camera records it; a white
balance off by up to 8% per channel; clipped; sRGB; 8-bit PNG or JPEG at quality 90:
benchmarks/make_photo_targets.py's `camera_exposure`; the files under OUT/photos and in the target) and runs
`warp-hair targets photo` with the recipe's flags and `--gains exif` (one lamp, as strong in both views, lit
them) into targets/blender_<name>_<png|jpeg>, adding truth.json and camera_truth.json. Its front photo is
`card`'s, the card and the hair it shadows marked as a photographer marks them (`card_masks`: `--card-mask`,
`--card-reflectance 0.18`, `--mask`), unless `--no-card`.
`fit` runs `warp-hair fit DIR -o OUT/fits/TARGET` (defaults) on each target in turn and records its exit status and
wall time; `table` prints the Markdown table of docs/acceptance.md ("Swatches Blender made"); `compare` renders, at
the true look, Blender's strands and the recipe's realisations in warp-hair against Cycles' images.

The swatches (the rig of the shipped cycles_* targets: 0.5 long, 0.4 wide, fibers of radius 0.004 in layers 0.0105
apart, over a rod of radius 0.25; an orthographic camera 0.36 wide, 64×64; front light (0.2, −0.3, −1), back light
(0, −0.15, 1), irradiance 3), each layer's roots spread by Blender's Poisson disk (Distribute Points on Faces,
minimum distance 1.025 fiber diameters: neighbours never start inside each other, gaps as they fall):
- straight: medium hair, 4 layers, straight, Blender's Hair Curves Noise (the Essentials asset) for their
  unevenness;
- wavy: dark hair, 4 layers, each layer's strands waving in step at a phase Blender's Random Value node draws
  per layer (waves out of step between layers), with a little Hair Curves Noise;
- clumped: chestnut hair, 4 layers, Blender's Clump Hair Curves (its own guides) and Frizz Hair Curves (kinks);
- thick: medium-dark hair, 12 layers (0.02% of the view's lines of sight pass through), with Hair Curves Noise.
The recipe measures off the strands what a photographer measures off a swatch (count, layers, waves' amplitude
and wavelength, the clumps and how far their tips close), rounded as written down.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))  # warp_hair, optimize, targets: also from bpy's Python

DEFAULT_OUT = HERE / "out" / "blender_swatches"
LENGTH, WIDTH, RADIUS, DRAPE, LAYER_GAP = 0.5, 0.4, 0.004, 0.25, 0.0105
# Half the depth of each layer's root strip: the roots' scatter in z.
STRIP_DEPTH = 0.001
# Roots no closer than this many fiber diameters (Blender's Poisson disk); the density is what it leaves.
MIN_DISTANCE, DENSITY_MAX = 1.025, 1.0e6
SEGMENTS = 128
ORTHO_WIDTH, RESOLUTION, DISTANCE = 0.36, 64, 3.0
LIGHTS = {"front": (0.2, -0.3, -1.0), "back": (0.0, -0.15, 1.0)}
IRRADIANCE = 3.0
ESSENTIALS = "datafiles/assets/geometry_nodes/procedural_hair_node_assets.blend"

LOOKS = {
    "medium": {"albedo": [0.45, 0.30, 0.18], "beta_m": 0.30, "beta_n": 0.40},
    "dark": {"albedo": [0.12, 0.09, 0.07], "beta_m": 0.25, "beta_n": 0.30},
    "chestnut": {"albedo": [0.55, 0.36, 0.22], "beta_m": 0.27, "beta_n": 0.38},
    "medium_dark": {"albedo": [0.30, 0.20, 0.12], "beta_m": 0.28, "beta_n": 0.36},
}
FIXED = {"alpha": 2.0, "eta": 1.55, "r_roughness_scale": 1.0}

# What Blender is asked for. "noise", "frizz", "clump": the Essentials assets' inputs; "waves": (amplitude,
# wavelength) in step within a layer, each layer's phase from Blender's Random Value node. "photo": the format the
# camera saves; "white_balance": the camera's miss of the light's colour.
SWATCHES = {
    "straight": {
        "look": "medium",
        "layers": 4,
        "seed": 11,
        "noise": {"Distance": 0.0002, "Scale": 3.0, "Seed": 5},
        "photo": "png",
        "white_balance": (1.06, 1.0, 0.92),
    },
    "wavy": {
        "look": "dark",
        "layers": 4,
        "seed": 23,
        "waves": (0.012, 0.25),
        "noise": {"Distance": 0.0001, "Scale": 3.0, "Seed": 7},
        "photo": "jpeg",
        "white_balance": (0.94, 1.0, 1.07),
    },
    "clumped": {
        "look": "chestnut",
        "layers": 4,
        "seed": 31,
        "clump": {"Guide Distance": 0.04, "Factor": 0.6, "Shape": 0.5, "Seed": 3},
        "frizz": {"Distance": 0.0002, "Seed": 9},
        "photo": "png",
        "white_balance": (1.08, 1.0, 0.93),
    },
    "thick": {
        "look": "medium_dark",
        "layers": 12,
        "seed": 41,
        "noise": {"Distance": 0.0002, "Scale": 3.0, "Seed": 13},
        "photo": "jpeg",
        "white_balance": (0.95, 1.0, 1.05),
    },
}


# The grey card the photographer holds in the front shot (docs/photos.md, "How to shoot"): an 18% grey Lambertian
# square facing the camera in the frame's bottom-left corner, above every strand (z = 0.1; the hair reaches 0.05),
# so that its face sees the light and the black sky only, as optimize/card_region.py assumes. Its shadow falls on
# the hair below and to the right of it; the photographer's mask leaves that hair out.
CARD = {"reflectance": 0.18, "x": (-0.17, -0.11), "y": (-0.17, -0.11), "z": 0.1}
# Pixels left out round the card and its shadow (the one next to them is 0.3-0.7% dimmer with the card, the light
# it would have had through the swatch from the shadowed strands; the next ones within 0.13%: Cycles at 1024 spp,
# blender_straight, the same seed with and without the card): one, and one more to spare.
CARD_MARGIN = 2


def truth(name: str) -> dict:
    return {**LOOKS[SWATCHES[name]["look"]], **FIXED}


# ---------------------------------------------------------------------------------------------------------------
# Blender (bpy)


def _node_tree(bpy, strips, spec):
    """Geometry Nodes: Blender's Poisson disk roots on the layers' strips, a straight line of SEGMENTS pieces along
    +y from each, and, with "waves", each point moved across by amplitude·sin(2π(y + L/2)/wavelength + φ) with φ
    from a Random Value node whose ID is the layer (so a layer's strands wave in step, layers at their own phases)."""
    tree = bpy.data.node_groups.new("swatch", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    out = nodes.new("NodeGroupOutput")
    info = nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = strips
    info.transform_space = "RELATIVE"
    points = nodes.new("GeometryNodeDistributePointsOnFaces")
    points.distribute_method = "POISSON"
    points.inputs["Distance Min"].default_value = MIN_DISTANCE * 2 * RADIUS
    points.inputs["Density Max"].default_value = DENSITY_MAX
    points.inputs["Seed"].default_value = spec["seed"]
    links.new(info.outputs["Geometry"], points.inputs["Mesh"])
    line = nodes.new("GeometryNodeCurvePrimitiveLine")
    line.inputs["Start"].default_value = (0.0, 0.0, 0.0)
    line.inputs["End"].default_value = (0.0, LENGTH, 0.0)
    resample = nodes.new("GeometryNodeResampleCurve")
    resample.inputs["Count"].default_value = SEGMENTS + 1
    links.new(line.outputs["Curve"], resample.inputs["Curve"])
    instance = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(points.outputs["Points"], instance.inputs["Points"])
    links.new(resample.outputs["Curve"], instance.inputs["Instance"])
    realize = nodes.new("GeometryNodeRealizeInstances")
    links.new(instance.outputs["Instances"], realize.inputs["Geometry"])
    geometry = realize.outputs["Geometry"]
    if "waves" in spec:
        amplitude, wavelength = spec["waves"]

        def math_node(operation, a, b=None):
            node = nodes.new("ShaderNodeMath")
            node.operation = operation
            for socket, value in zip(node.inputs, (a, b)):
                if value is None:
                    continue
                if isinstance(value, (int, float)):
                    socket.default_value = value
                else:
                    links.new(value, socket)
            return node.outputs[0]

        xyz = nodes.new("ShaderNodeSeparateXYZ")
        links.new(nodes.new("GeometryNodeInputPosition").outputs["Position"], xyz.inputs["Vector"])
        layer = math_node("ROUND", math_node("DIVIDE", math_node("MULTIPLY", xyz.outputs["Z"], -1.0), LAYER_GAP))
        to_int = nodes.new("FunctionNodeFloatToInt")
        links.new(layer, to_int.inputs["Float"])
        phase = nodes.new("FunctionNodeRandomValue")
        phase.data_type = "FLOAT"
        phase.inputs["Min"].default_value = 0.0
        phase.inputs["Max"].default_value = 2 * math.pi
        phase.inputs["Seed"].default_value = spec["seed"]
        links.new(to_int.outputs["Integer"], phase.inputs["ID"])
        angle = math_node(
            "ADD", math_node("MULTIPLY", math_node("ADD", xyz.outputs["Y"], LENGTH / 2), 2 * math.pi / wavelength)
        )
        links.new(phase.outputs["Value"], angle.node.inputs[1])
        swing = math_node("MULTIPLY", math_node("SINE", angle), amplitude)
        offset = nodes.new("ShaderNodeCombineXYZ")
        links.new(swing, offset.inputs["X"])
        move = nodes.new("GeometryNodeSetPosition")
        links.new(geometry, move.inputs["Geometry"])
        links.new(offset.outputs["Vector"], move.inputs["Offset"])
        geometry = move.outputs["Geometry"]
    links.new(geometry, out.inputs["Geometry"])
    return tree


def _strips(bpy, layers):
    """One mesh of `layers` thin quads at the roots (y = −L/2), layer k at depth z = −k·LAYER_GAP, hidden from
    renders: the surface Blender's Poisson disk spreads each layer's roots over."""
    verts, faces = [], []
    for k in range(layers):
        z = -k * LAYER_GAP
        base = len(verts)
        verts += [(-WIDTH / 2, -LENGTH / 2, z - STRIP_DEPTH), (WIDTH / 2, -LENGTH / 2, z - STRIP_DEPTH)]
        verts += [(WIDTH / 2, -LENGTH / 2, z + STRIP_DEPTH), (-WIDTH / 2, -LENGTH / 2, z + STRIP_DEPTH)]
        faces.append((base, base + 1, base + 2, base + 3))
    mesh = bpy.data.meshes.new("strips")
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = bpy.data.objects.new("strips", mesh)
    obj.hide_render = True
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _essentials(bpy, obj, name, inputs):
    """A NODES modifier running the Essentials hair node group `name` (make_blender_groom.py's way)."""
    if name not in bpy.data.node_groups:
        path = Path(bpy.utils.resource_path("LOCAL")) / ESSENTIALS
        with bpy.data.libraries.load(str(path)) as (_, data):
            data.node_groups = [name]
    group = bpy.data.node_groups[name]
    modifier = obj.modifiers.new(name, "NODES")
    modifier.node_group = group
    ids = {
        item.name: item.identifier
        for item in group.interface.items_tree
        if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.socket_type != "NodeSocketGeometry"
    }
    for key, value in inputs.items():
        modifier[ids[key]] = value
    return modifier


def blender_strands(bpy, name):
    """The swatch `name`'s strands as Blender makes them, flat (before the drape): (S, SEGMENTS + 1, 3) float64,
    roots at y = −L/2, and the clump guide of each strand (−1 without clumps)."""
    spec = SWATCHES[name]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    strips = _strips(bpy, spec["layers"])
    curves = bpy.data.hair_curves.new("swatch")
    obj = bpy.data.objects.new("swatch", curves)
    bpy.context.scene.collection.objects.link(obj)
    obj.modifiers.new("swatch", "NODES").node_group = _node_tree(bpy, strips, spec)
    if "clump" in spec:
        _essentials(bpy, obj, "Clump Hair Curves", spec["clump"])
    if "frizz" in spec:
        _essentials(bpy, obj, "Frizz Hair Curves", spec["frizz"])
    if "noise" in spec:
        _essentials(bpy, obj, "Hair Curves Noise", spec["noise"])
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    count = len(evaluated.curves)
    sizes = {curve.points_length for curve in evaluated.curves}
    if sizes != {SEGMENTS + 1}:
        raise RuntimeError(f"{name}: Blender's curves have {sorted(sizes)} points, not {SEGMENTS + 1}")
    flat = np.empty(count * (SEGMENTS + 1) * 3, dtype=np.float32)
    evaluated.position_data.foreach_get("vector", flat)
    guide = np.full(count, -1)
    attribute = evaluated.attributes.get("guide_curve_index")
    if attribute is not None and attribute.domain == "CURVE":
        attribute.data.foreach_get("value", guide)
    return flat.reshape(count, SEGMENTS + 1, 3).astype(np.float64), guide


def drape(points):
    """The flat swatch laid over the rod (radius DRAPE, axis along x, top at z = 0): the rig of the generators
    (warp_hair/geometry/generators.py `_swatch_assembly`), so that the recipe's drape radius is the rod's."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    bent = DRAPE + z
    return np.stack([x, bent * np.sin(y / DRAPE), bent * np.cos(y / DRAPE) - DRAPE], axis=-1)


def measure(name, flat, guide):
    """What a photographer measures off the swatch, as written down: the strand count and, where they apply, the
    waves' amplitude and wavelength (each strand's strongest Fourier component across the swatch, median over
    strands, two significant figures) and the clumps (how many, and how far a strand's tip has closed on its
    clump's guide: 1 − median of tip distance / root distance, one decimal)."""
    spec = SWATCHES[name]
    found = {"count": int(len(flat)), "layers": spec["layers"]}
    if "waves" in spec:
        swing = flat[..., 0] - flat[:, :1, 0]
        swing = swing[:, :-1] - swing[:, :-1].mean(axis=1, keepdims=True)  # one period of the sampled length
        spectrum = np.abs(np.fft.rfft(swing, axis=1))
        k = np.argmax(spectrum[:, 1:], axis=1) + 1
        amplitude = 2 * spectrum[np.arange(len(k)), k] / swing.shape[1]
        found["amplitude"] = float(f"{np.median(amplitude):.2g}")
        found["wavelength"] = float(f"{np.median(LENGTH / k):.2g}")
    if "clump" in spec:
        guides = np.unique(guide[guide >= 0])
        found["clumps"] = int(len(guides))
        joined = (guide >= 0) & (guide != np.arange(len(guide)))
        root = np.linalg.norm(flat[joined, 0, ::2] - flat[guide[joined], 0, ::2], axis=-1)
        tip = np.linalg.norm(flat[joined, -1, ::2] - flat[guide[joined], -1, ::2], axis=-1)
        found["clump_strength"] = float(f"{1 - np.median(tip / root):.1f}")
    return found


def recipe_flags(found) -> list[str]:
    """`warp-hair targets photo` flags for the swatch as measured: the rig's dimensions and its fibers' recipe."""
    flags = ["--rig", "draped", "--width", f"{WIDTH:g}", "--length", f"{LENGTH:g}", "--count", str(found["count"])]
    flags += ["--layers", str(found["layers"]), "--fiber-radius", f"{RADIUS:g}", "--drape", f"{DRAPE:g}"]
    flags += ["--distance", f"{DISTANCE:g}", "--ortho-width", f"{ORTHO_WIDTH:g}", "--resolution", str(RESOLUTION)]
    if "amplitude" in found:
        # A combed wavy swatch's strands in step within a layer, the layers' waves out of step.
        flags += ["--waves", f"{found['amplitude']:g},{found['wavelength']:g}"]
        flags += ["--phase-jitter", "0", "--layer-phase-jitter", "1"]
    if "clumps" in found:
        flags += ["--clumps", str(found["clumps"]), "--clump-strength", f"{found['clump_strength']:g}"]
    return flags


def recipe_fibers(found) -> dict:
    """The [fibers] table `targets photo` writes for those flags (optimize/photo_target.py `_rig_fibers`), so that
    the EXR target and the photo target state the same recipe."""
    from optimize.photo_target import SWATCH_FLAGS, _rig_fibers

    args = SimpleNamespace(
        count=found["count"], layers=found["layers"], length=LENGTH, width=WIDTH, fiber_radius=RADIUS, drape=DRAPE
    )
    for flag in SWATCH_FLAGS:
        setattr(args, flag, None)
    if "amplitude" in found:
        args.waves, args.phase_jitter, args.layer_phase_jitter = (found["amplitude"], found["wavelength"]), 0.0, 1.0
    if "clumps" in found:
        args.clumps, args.clump_strength = found["clumps"], found["clump_strength"]
    return _rig_fibers("draped", args)


def _toml(value) -> str:
    from optimize.photo_target import _toml as toml

    return toml(value)


def scene_text(name, view, fibers, spp) -> str:
    """A scene file of the EXR target: the camera and light of `view`, the recipe's fibers, the truth's look."""
    tables = {
        "camera": {
            "type": "orthographic",
            "origin": [0.0, 0.0, DISTANCE],
            "target": [0.0, 0.0, 0.0],
            "up": [0.0, 1.0, 0.0],
            "width": ORTHO_WIDTH,
            "resolution": [RESOLUTION, RESOLUTION],
        },
        "lights": {"type": "directional", "direction": list(LIGHTS[view]), "irradiance": [IRRADIANCE] * 3},
        "fibers": fibers,
        "hair": {key: value for key, value in truth(name).items() if key != "r_roughness_scale"},
        "render": {"spp": spp, "max_depth": 64, "seed": 1},
    }
    lines = [
        f"# blender_{name}: strands Blender made (benchmarks/blender_swatch_acceptance.py), rendered by Cycles 4.5;",
        "# [fibers] is the recipe a photographer writes down, not the strands: the fit renders its realisations.",
        f"# {'Front' if view == 'front' else 'Back'}-lit view.",
    ]
    for table, values in tables.items():
        lines += ["", f"[[{table}]]" if table == "lights" else f"[{table}]"]
        lines += [f"{key} = {_toml(value)}" for key, value in values.items()]
    return "\n".join(lines) + "\n"


def make(name, spp, threads, out, root):
    """Blender's strands, Cycles' two views, and the EXR target targets/blender_<name> (module docstring)."""
    import bpy
    from cycles_peer import render_cycles

    from warp_hair.geometry import FiberAssembly
    from warp_hair.geometry.formats import save_fibers
    from warp_hair.geometry.interpenetration import interpenetration
    from warp_hair.io import write_exr
    from warp_hair.scene import load_scene

    start = time.perf_counter()
    flat, guide = blender_strands(bpy, name)
    strands = FiberAssembly.from_arrays(drape(flat), RADIUS)
    found = measure(name, flat, guide)
    overlaps = interpenetration(strands)
    (out / "strands").mkdir(parents=True, exist_ok=True)
    save_fibers(strands, out / "strands" / f"{name}.hair")
    print(f"{name}: Blender made {found} in {time.perf_counter() - start:.1f} s; {overlaps.pairs} strand pairs touch")
    directory = root / f"blender_{name}"
    directory.mkdir(parents=True, exist_ok=True)
    fibers = recipe_fibers(found)
    record = {
        "blender": {k: v for k, v in SWATCHES[name].items() if k not in ("photo", "white_balance")},
        "rig": {"length": LENGTH, "width": WIDTH, "radius": RADIUS, "drape": DRAPE, "layer_gap": LAYER_GAP},
        "measured": found,
        "recipe_flags": recipe_flags(found),
        "interpenetrating_pairs": int(overlaps.pairs),
        "cycles_spp": spp,
        "seconds": {},
    }
    for view in LIGHTS:
        text = scene_text(name, view, fibers, spp)
        (directory / f"scene_{view}.toml").write_text(text, encoding="utf-8")
        scene = load_scene(directory / f"scene_{view}.toml")
        start = time.perf_counter()
        image = render_cycles(bpy, scene, spp, threads=threads, seed=1, fibers=strands)
        record["seconds"][view] = round(time.perf_counter() - start, 1)
        write_exr(directory / f"{view}.exr", image)
        print(f"  {view}: Cycles {spp} spp, {record['seconds'][view]:.0f} s, mean {image.mean(axis=(0, 1))}")
    target = [
        f"# blender_{name}: a draped swatch whose strands Blender made (Geometry Nodes hair curves), rendered by",
        "# Cycles 4.5, front- and back-lit; the scenes give the recipe only. Made by",
        f"# `benchmarks/blender_swatch_acceptance.py make {name}` (blender.json: what Blender was asked for).",
        'renderer = "cycles"',
        'realisations = "random"',
    ]
    for view in LIGHTS:
        target += ["", "[[images]]", f'scene = "scene_{view}.toml"', f'image = "{view}.exr"']
    target += ["", *arrangement_lines(fibers)]
    (directory / "target.toml").write_text("\n".join(target) + "\n", encoding="utf-8")
    (directory / "truth.json").write_text(json.dumps(truth(name), indent=2) + "\n", encoding="utf-8")
    (directory / "blender.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return directory


def make_card(name, spp, threads, out, root):
    """OUT/card/<name>: the front view again with the grey card (CARD) in the shot, Cycles at `spp`, and
    card.json with the depths of the strands beneath the card, from which `card_masks` paints the masks a
    photographer would."""
    import bpy
    from cycles_peer import render_cycles

    from warp_hair.geometry import FiberAssembly
    from warp_hair.io import write_exr
    from warp_hair.scene import load_scene

    flat, _ = blender_strands(bpy, name)
    points = drape(flat)
    strands = FiberAssembly.from_arrays(points, RADIUS)
    scene = load_scene(root / f"blender_{name}" / "scene_front.toml")
    start = time.perf_counter()
    image = render_cycles(bpy, scene, spp, threads=threads, seed=1, fibers=strands, props=_card_prop)
    directory = out / "card" / name
    directory.mkdir(parents=True, exist_ok=True)
    write_exr(directory / "front.exr", image)
    near = points.reshape(-1, 3)
    (x0, x1), (y0, y1) = CARD["x"], CARD["y"]
    near = near[(near[:, 0] > x0 - 0.1) & (near[:, 0] < x1 + 0.1) & (near[:, 1] > y0 - 0.1) & (near[:, 1] < y1 + 0.1)]
    depths = [float(CARD["z"] - near[:, 2].max()), float(CARD["z"] - near[:, 2].min())]
    (directory / "card.json").write_text(json.dumps({"card": CARD, "depths": depths, "spp": spp}, indent=2) + "\n")
    print(f"{name}: front view with the card, Cycles {spp} spp, {time.perf_counter() - start:.0f} s", flush=True)
    return directory


def _card_prop(bpy):
    """CARD as a Blender quad with a Diffuse BSDF (Lambertian: roughness 0) of its reflectance."""
    (x0, x1), (y0, y1), z = CARD["x"], CARD["y"], CARD["z"]
    mesh = bpy.data.meshes.new("grey_card")
    mesh.from_pydata([(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)], [], [(0, 1, 2, 3)])
    material = bpy.data.materials.new("grey_card")
    material.use_nodes = True
    bsdf = material.node_tree.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*[CARD["reflectance"]] * 3, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0
    output = material.node_tree.nodes.get("Material Output") or material.node_tree.nodes.new("ShaderNodeOutputMaterial")
    material.node_tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    mesh.materials.append(material)
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("grey_card", mesh))


def card_masks(depths, margin: int = CARD_MARGIN) -> tuple:
    """((H, W) card, (H, W) hair) for the front view: the pixels wholly on CARD; the hair pixels that count,
    leaving out every pixel the card touches and its shadow, swept over the strands' `depths` (min, max) beneath
    it, and `margin` pixels more all round (the light that would have spread to them through the swatch from
    the shadowed hair)."""
    from scipy.ndimage import binary_dilation

    step = ORTHO_WIDTH / RESOLUTION
    edges = -ORTHO_WIDTH / 2 + step * np.arange(RESOLUTION + 1)  # x left to right; y top to bottom is −edges
    (x0, x1), (y0, y1) = CARD["x"], CARD["y"]
    direction = np.asarray(LIGHTS["front"], dtype=np.float64)
    shift = direction[:2] / -direction[2]  # across the image per unit of depth the light falls
    near, far = depths[0] * shift, depths[1] * shift

    def covered(lo_x, hi_x, lo_y, hi_y, wholly):
        left, right, top, bottom = edges[:-1], edges[1:], -edges[:-1], -edges[1:]
        if wholly:
            return ((bottom >= lo_y) & (top <= hi_y))[:, None] & ((left >= lo_x) & (right <= hi_x))[None, :]
        return ((top > lo_y) & (bottom < hi_y))[:, None] & ((right > lo_x) & (left < hi_x))[None, :]

    card = covered(x0, x1, y0, y1, True)
    touched = covered(x0, x1, y0, y1, False)
    low, high = np.minimum(near, far), np.maximum(near, far)
    shadow = covered(x0 + low[0], x1 + high[0], y0 + low[1], y1 + high[1], False)
    out = touched | shadow
    if margin > 0:  # `margin` pixels more all round, diagonals included
        out = binary_dilation(out, structure=np.ones((3, 3), bool), iterations=margin)
    return card, ~out


# ---------------------------------------------------------------------------------------------------------------
# Photo-like targets, fits, the table (the main environment)


def make_photo(name, root, out, card=True):
    """targets/blender_<name>_<png|jpeg>: the EXR target's two renders as a camera saves them, through
    `warp-hair targets photo` with the recipe's flags; truth.json and camera_truth.json beside. With `card`, the
    front view is `make_card`'s (the grey card in the shot), marked as a photographer marks it."""
    from make_photo_targets import FORMATS, JPEG_QUALITY, camera_exposure
    from PIL import Image

    from warp_hair.io import read_exr
    from warp_hair.photo import write_photo

    source = root / f"blender_{name}"
    record = json.loads((source / "blender.json").read_text(encoding="utf-8"))
    kind = SWATCHES[name]["photo"]
    white_balance = np.array(SWATCHES[name]["white_balance"])
    directory = root / f"blender_{name}_{kind}"
    photos = out / "photos" / name
    photos.mkdir(parents=True, exist_ok=True)
    shot = out / "card" / name
    if card and not (shot / "card.json").is_file():
        raise SystemExit(f"{shot / 'card.json'} not found: run `card {name}` first (bpy), or `photo --no-card`")
    if directory.exists():
        shutil.rmtree(directory)
    command = ["warp-hair", "targets", "photo", str(directory)]
    gains = {}
    for view, light in LIGHTS.items():
        image, _ = read_exr(shot / "front.exr" if card and view == "front" else source / f"{view}.exr")
        exposure, exif = camera_exposure(image)
        path = photos / f"{view}{FORMATS[kind]}"
        scaled = image * np.float32(exposure) * white_balance.astype(np.float32)
        write_photo(path, scaled, quality=JPEG_QUALITY, exif=exif)
        gains[view] = exposure * white_balance[1]
        command += ["--image", str(path), "--light", ",".join(f"{c:g}" for c in light)]
    if card:  # the card in the front shot only: the back light does not reach its face
        marked, hair = card_masks(json.loads((shot / "card.json").read_text(encoding="utf-8"))["depths"])
        masks = {"front_card": marked, "front_hair": hair, "back_hair": np.ones_like(hair)}
        for stem, mask in masks.items():
            Image.fromarray((mask * 255).astype(np.uint8), "L").save(photos / f"{stem}.png")
        command += ["--card-mask", str(photos / "front_card.png"), "none"]
        command += ["--card-reflectance", str(CARD["reflectance"])]
        command += ["--mask", str(photos / "front_hair.png"), str(photos / "back_hair.png")]
    command += ["--gains", "exif"]  # one lamp of the same irradiance lit both views (LIGHTS, IRRADIANCE)
    command += record["recipe_flags"]
    print("$", " ".join(command), flush=True)
    subprocess.run(command, check=True)
    for view in LIGHTS:  # the photos themselves, for `targets photo` again: the files it names in the EXRs' headers
        shutil.copy(photos / f"{view}{FORMATS[kind]}", directory)
    shutil.copy(source / "truth.json", directory / "truth.json")
    camera = {"gains": gains, "white_balance": (white_balance / white_balance[1]).tolist()}
    (directory / "camera_truth.json").write_text(json.dumps(camera, indent=2) + "\n", encoding="utf-8")
    return directory


def arrangement_lines(fibers) -> list[str]:
    """The EXR targets' [arrangement]: what `targets photo` writes for the same recipe (issue 43, item 1)."""
    from optimize.arrangement import photo_defaults

    return [
        "# How the strands lie, which the recipe cannot say: the prior `targets photo` writes",
        "# (optimize/arrangement.py).",
        "[arrangement]",
        *(f"{key} = [{low}, {high}]" for key, (low, high) in photo_defaults(fibers).items()),
    ]


def target_names(names, only=None) -> list[str]:
    """The targets of swatches `names`: the EXR one and the photo one of each, or `only` ("exr", "photo")."""
    kinds = {"exr": ("",), "photo": ("_{photo}",)}.get(only, ("", "_{photo}"))
    return [f"blender_{name}" + kind.format(photo=SWATCHES[name]["photo"]) for name in names for kind in kinds]


def run_fit(target, root, out, threads):
    """`warp-hair fit DIR -o OUT` as a user runs it; its exit status and wall time beside params.json."""
    fit_dir = out / "fits" / target
    command = ["warp-hair", "fit", str(root / target), "-o", str(fit_dir)]
    if threads:
        command += ["--threads", str(threads)]
    print("$", " ".join(command), flush=True)
    start = time.perf_counter()
    status = subprocess.run(command).returncode
    seconds = time.perf_counter() - start
    fit_dir.mkdir(parents=True, exist_ok=True)
    run = {"command": " ".join(command[:5]), "status": status, "wall_seconds": round(seconds, 1)}
    (fit_dir / "run.json").write_text(json.dumps(run, indent=2) + "\n", encoding="utf-8")
    print(f"{target}: exit status {status}, {seconds:.0f} s", flush=True)


CONTROLS = ("albedo", "beta_m", "beta_n")
LABELS = ("a_r", "a_g", "a_b", "β_m", "β_n")


def _flat(values: dict) -> np.ndarray:
    return np.concatenate([np.atleast_1d(np.asarray(values[name], dtype=np.float64)) for name in CONTROLS])


def table(names, root, out, only=None) -> str:
    from optimize.settings import BOUNDS

    bounds = np.array([BOUNDS["albedo"]] * 3 + [BOUNDS["beta_m"], BOUNDS["beta_n"]])
    rows = [
        "| target | truth albedo / β_m / β_n | fitted ± σ | error | \\|error\\|/σ | each within bound or 2σ | χ²/dof | "
        "exit status | wall time |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    ratios, kept = [], []
    for target in target_names(names, only):
        fit_dir = out / "fits" / target
        if not (fit_dir / "run.json").is_file():
            continue
        run = json.loads((fit_dir / "run.json").read_text(encoding="utf-8"))
        params_file = fit_dir / "params.json"
        if not params_file.is_file():
            rows.append(f"| {target} | | no params.json | | | | | {run['status']} | {run['wall_seconds']:.0f} s |")
            continue
        p = json.loads(params_file.read_text(encoding="utf-8"))
        value, sigma, true = _flat(p["fitted"]), _flat(p["uncertainty"]), _flat(p["true"])
        error = value - true
        ratio = np.abs(error) / sigma
        ratios.append(ratio)
        ok = (np.abs(error) <= bounds) | (ratio <= 2)
        verdict = "yes" if ok.all() else "no: " + ", ".join(label for label, o in zip(LABELS, ok) if not o)
        if p.get("failed"):
            verdict = f"failed ({verdict})"  # its values are not a result; the fit said so
        else:
            kept.append(ratio)
        chi2 = p.get("goodness_of_fit", {}).get("chi2_per_dof", float("nan"))

        def triple(v, f):
            return f"({f.format(v[0])}, {f.format(v[1])}, {f.format(v[2])}) / {f.format(v[3])} / {f.format(v[4])}"

        rows.append(
            f"| {target} | {triple(true, '{:.2f}')} "
            f"| ({value[0]:.3f}, {value[1]:.3f}, {value[2]:.3f}) ± ({sigma[0]:.3f}, {sigma[1]:.3f}, {sigma[2]:.3f}) "
            f"/ {value[3]:.3f} ± {sigma[3]:.3f} / {value[4]:.3f} ± {sigma[4]:.3f} "
            f"| {triple(error, '{:+.3f}')} | {triple(ratio, '{:.1f}')} "
            f"| {verdict} "
            f"| {chi2:.2f} | {run['status']}{' (failed)' if p.get('failed') else ''} | {run['wall_seconds']:.0f} s |"
        )
    for what, group in (("all", ratios), ("that did not say they failed", kept)):
        if group:
            r = np.concatenate(group)
            rows.append(
                f"\n{len(group)} fits ({what}), {r.size} control components: {np.mean(r <= 2):.1%} within 2σ, "
                f"{np.mean(r <= 3):.1%} within 3σ, largest {r.max():.2f}σ (the promise: ≥ 95% and 100%)"
            )
    return "\n".join(rows)


def compare(name, spp, threads, out, root, realisations=4):
    """Per view, warp-hair at the truth against Cycles' image (channel means, ours / Cycles'): on Blender's own
    strands (`[render] interpenetration = "exit"`, Cycles' rule where tubes overlap), which tells the renderers'
    disagreement, and on realisations 1..`realisations` of the recipe (what the fit renders), which tells what the
    strands' arrangement costs at the true look."""
    import dataclasses

    from warp_hair.geometry.formats import load_fibers
    from warp_hair.io import read_exr
    from warp_hair.realisation import realisation
    from warp_hair.renderer.render import render
    from warp_hair.scene import load_scene

    directory = root / f"blender_{name}"
    strands = load_fibers(out / "strands" / f"{name}.hair")
    for view in LIGHTS:
        scene = load_scene(directory / f"scene_{view}.toml")
        settings = dataclasses.replace(scene.render, spp=spp, seed=7)
        cycles = read_exr(directory / f"{view}.exr")[0].mean(axis=(0, 1))
        own = dataclasses.replace(scene, fibers=strands, render=dataclasses.replace(settings, interpenetration="exit"))
        start = time.perf_counter()
        ratio = render(own, threads=threads).mean(axis=(0, 1)) / cycles
        print(f"{name} {view}: warp-hair on Blender's strands / Cycles {np.round(ratio, 4)}", flush=True)
        draws = []
        for index in range(1, realisations + 1):
            other = dataclasses.replace(realisation(scene, index), render=settings)
            draws.append(render(other, threads=threads).mean(axis=(0, 1)) / cycles)
        draws = np.array(draws)
        print(
            f"{name} {view}: the recipe's realisations 1-{realisations} / Cycles {np.round(draws.mean(0), 4)} "
            f"(spread {np.round(draws.std(0, ddof=1), 4)}); {time.perf_counter() - start:.0f} s",
            flush=True,
        )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", choices=("make", "card", "photo", "fit", "table", "compare"))
    parser.add_argument("names", nargs="*", help=f"swatches, of {', '.join(SWATCHES)} (default all)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--targets", type=Path, default=ROOT / "targets", help="where the targets go")
    parser.add_argument("--spp", type=int, default=None, help="make: Cycles' samples (1024); compare: ours (256)")
    parser.add_argument("--threads", type=int, help="make: Cycles' (2); fit: warp-hair's (its default: all cores)")
    parser.add_argument("--no-card", action="store_true", help="photo: no grey card in the front shot")
    parser.add_argument("--only", choices=("exr", "photo"), help="fit, table: the linear-EXR or the photo targets only")
    args = parser.parse_args(argv)
    names = args.names or list(SWATCHES)
    unknown = sorted(set(names) - set(SWATCHES))
    if unknown:
        parser.error(f"unknown swatch(es) {unknown}; allowed: {', '.join(SWATCHES)}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.action == "make":
        for name in names:
            print(make(name, args.spp or 1024, args.threads or 2, args.out, args.targets), flush=True)
    elif args.action == "card":
        for name in names:
            print(make_card(name, args.spp or 1024, args.threads or 2, args.out, args.targets), flush=True)
    elif args.action == "photo":
        for name in names:
            print(make_photo(name, args.targets, args.out, card=not args.no_card), flush=True)
    elif args.action == "fit":
        for target in target_names(names, args.only):
            run_fit(target, args.targets, args.out, args.threads)
    elif args.action == "table":
        print(table(names, args.targets, args.out, args.only))
    else:
        for name in names:
            compare(name, args.spp or 256, args.threads or 2, args.out, args.targets)


if __name__ == "__main__":
    main()
