"""Hair as it grows in Blender Cycles (opt-in: `pytest -m bpy`): what its Hair Info node gives a strand, and the
exported look with variation rendered by Cycles against warp-hair.

The probes render a hair `Curves` object (benchmarks/cycles_peer.py's translation) whose material emits one Hair
Info output as its colour, through a flat orthographic camera: a pixel inside a strand's tube is that output there.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

from warp_hair.export import export
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.curves import BASIS_MATRICES
from warp_hair.model.params import HairParams
from warp_hair.model.variation import strand_looks, strand_random, tip_profile
from warp_hair.scene import scene_from_dict

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
PIXEL = 0.01  # scene units per pixel of the probes


@pytest.fixture(scope="module")
def cycles():
    """(bpy, render_cycles) of benchmarks/cycles_peer.py."""
    bpy = pytest.importorskip("bpy", reason="bpy 4.5 (Python 3.11) is the `blender` extra")
    sys.path.insert(0, str(BENCHMARKS))
    try:
        from cycles_peer import render_cycles
    finally:
        sys.path.remove(str(BENCHMARKS))
    return bpy, render_cycles


def hair_info_probe(output):
    """A material that emits Hair Info's `output` (a float) as its colour, with strength 1."""

    def make(bpy):
        material = bpy.data.materials.new(f"probe {output}")
        material.use_nodes = True
        nodes, links = material.node_tree.nodes, material.node_tree.links
        nodes.clear()
        info = nodes.new("ShaderNodeHairInfo")
        emission = nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 1.0
        links.new(info.outputs[output], emission.inputs["Color"])
        out = nodes.new("ShaderNodeOutputMaterial")
        out.target = "CYCLES"
        links.new(emission.outputs["Emission"], out.inputs["Surface"])
        return material

    return make


def probe(cycles, fibers, output, resolution, spp=64, material=None):
    """Cycles' image of `fibers` (in the z = 0 plane, y from 0 to 1) emitting Hair Info's `output` (or what
    `material` emits), seen head-on with PIXEL units per pixel, centred on (0, 0.5)."""
    bpy, render_cycles = cycles
    scene = scene_from_dict(
        {
            "camera": {
                "type": "orthographic",
                "origin": [0.0, 0.5, 3.0],
                "target": [0.0, 0.5, 0.0],
                "up": [0.0, 1.0, 0.0],
                "width": resolution[0] * PIXEL,
                "resolution": list(resolution),
            },
            "lights": [{"type": "environment", "radiance": [0.0, 0.0, 0.0]}],
            "fibers": {"generator": "swatch", "count": 1, "layers": 1},  # replaced by `fibers`
            "hair": {"albedo": [0.5, 0.5, 0.5]},
            "render": {"spp": spp, "max_depth": 2},
        }
    )
    return render_cycles(bpy, scene, spp, threads=2, fibers=fibers, material=material or hair_info_probe(output))


def column(x, width):
    """The pixel column whose centre is at x (the image spans [−width/2, width/2])."""
    return int(round((x + width / 2) / PIXEL - 0.5))


@pytest.mark.bpy
def test_cycles_random_is_each_strands_hash(cycles):
    """Hair Info's Random of curve k is hash_uint2_to_float(k, 0): warp-hair's strand_random(S, 0), to the bit."""
    strands = 32
    xs = (np.arange(strands) - (strands - 1) / 2) * 0.1
    fibers = FiberAssembly.from_strands([([[x, 0.0, 0.0], [x, 0.5, 0.0], [x, 1.0, 0.0]], 0.03) for x in xs])
    image = probe(cycles, fibers, "Random", (320, 40), spp=1)  # one sample: the film's sum adds no rounding
    seen = image[20, [column(x, 3.2) for x in xs]]
    np.testing.assert_array_equal(seen, np.repeat(strand_random(strands, 0)[:, None], 3, axis=1))


def catmull_rom_parameter(ys, y):
    """(segment, u) where Cycles' Catmull-Rom curve through the collinear vertices at heights ys (its end vertices
    repeated, as Cycles does) passes height y: each segment sampled finely and inverted (monotone here)."""
    padded = np.concatenate([ys[:1], ys, ys[-1:]])
    u = np.linspace(0.0, 1.0, 4001)
    powers = np.stack([u**3, u**2, u, np.ones_like(u)], axis=1)
    for i in range(len(ys) - 1):
        heights = powers @ BASIS_MATRICES["catmullRom"] @ padded[i : i + 4]
        if heights[0] <= y <= heights[-1]:
            return i, float(np.interp(y, heights, u))
    raise ValueError(y)


@pytest.mark.bpy
def test_cycles_intercept_is_the_vertices_arc_length_fraction_along_the_curve_parameter(cycles):
    """Hair Info's Intercept at a vertex is its arc-length fraction along the polyline (FiberAssembly's
    segment_arc_fractions), linearly interpolated in the curve's parameter between vertices; not the parametric
    fraction (segment + u) / segments, which strands of uneven segments tell apart."""
    heights = [[0.0, 0.1, 0.18, 0.5, 0.62, 0.75, 1.0], [0.0, 0.6, 1.0], [0.0, 0.25, 0.5, 0.75, 1.0]]
    xs = [-0.1, 0.0, 0.1]
    fibers = FiberAssembly.from_strands([([[x, y, 0.0] for y in ys], 0.03) for x, ys in zip(xs, heights)])
    start, span = fibers.segment_arc_fractions()
    image = probe(cycles, fibers, "Intercept", (40, 100))
    rows = np.arange(3, 97)  # away from the strands' rounded-off ends
    first = np.concatenate([[0], np.cumsum([len(ys) - 1 for ys in heights])])
    for k, ys in enumerate(heights):
        seen = image[rows, column(xs[k], 0.4), 0]
        along, parametric = [], []
        for row in rows:
            segment, u = catmull_rom_parameter(np.array(ys), 1.0 - (row + 0.5) * PIXEL)
            along.append(start[first[k] + segment] + span[first[k] + segment] * u)
            parametric.append((segment + u) / (len(ys) - 1))
        # A pixel averages the intercept over its height (0.01 of the strand): 64 samples leave ~4e-4 of noise.
        assert np.max(np.abs(seen - along)) < 3e-3, k
        if k < 2:  # uneven segments
            assert np.max(np.abs(seen - parametric)) > 0.05, k


def exported_absorption_probe(params, directory):
    """The look's exported material (warp-hair export --to cycles, run) with the output of its absorption nodes
    emitted instead of the hair BSDF: Cycles' σ_a where a camera ray meets a strand."""

    def make(bpy):
        import runpy

        script = Path(directory) / "hair_cycles.py"
        export(params, "cycles", script)
        material = runpy.run_path(str(script))["make_material"]()
        nodes, links = material.node_tree.nodes, material.node_tree.links
        (hair,) = [n for n in nodes if n.bl_idname == "ShaderNodeBsdfHairPrincipled"]
        (absorption,) = [k for k in links if k.to_socket == hair.inputs["Absorption Coefficient"]]
        emission = nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 1.0
        links.new(absorption.from_socket, emission.inputs["Color"])
        (output,) = [n for n in nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
        links.new(emission.outputs["Emission"], output.inputs["Surface"])
        return material

    return make


@pytest.mark.bpy
@pytest.mark.parametrize(
    "params",
    [
        HairParams(albedo=(0.55, 0.4, 0.25), beta_n=0.35, color_spread=0.4, roughness_spread=0.25, tip_absorption=0.3),
        HairParams(eumelanin=1.3, pheomelanin=0.2, color_spread=0.4, tip_absorption=0.3),
    ],
    ids=["albedo", "melanin"],
)
def test_cycles_renders_the_exported_absorption_as_strand_looks(cycles, tmp_path, params):
    """Cycles evaluates the exported Math nodes to warp-hair's σ_a of each strand (its Random) along its length
    (its Intercept, as Cycles gives it: test above), to float32 precision."""
    strands, heights = 24, np.linspace(0.0, 1.0, 9)
    xs = (np.arange(strands) - (strands - 1) / 2) * 0.1
    fibers = FiberAssembly.from_strands([([[x, y, 0.0] for y in heights], 0.03) for x in xs])
    start, span = fibers.segment_arc_fractions()
    image = probe(cycles, fibers, "Random", (240, 100), spp=1, material=exported_absorption_probe(params, tmp_path))
    rows = np.arange(2, 98)
    intercept = []
    for row in rows:
        segment, u = catmull_rom_parameter(heights, 1.0 - (row + 0.5) * PIXEL)
        intercept.append(start[segment] + span[segment] * u)  # every strand's segments alike
    looks = strand_looks(params, strand_random(strands))
    want = (
        looks.sigma_a[None, :, :]
        * tip_profile(np.array(intercept), params.tip_absorption, params.tip_length)[:, None, None]
    )
    seen = image[rows][:, [column(x, 2.4) for x in xs]]
    # One sample per pixel: its intercept lies within half a pixel (0.005) of the row's centre.
    slope = np.abs(np.gradient(want, 0.01, axis=0)).max(axis=0)
    np.testing.assert_array_less(np.abs(seen - want), 0.005 * slope + 1e-5 * want)
    assert np.ptp(want[:, :, 0], axis=1).min() > 0.1 * want[:, :, 0].mean()  # strands differ


@pytest.mark.bpy
@pytest.mark.parametrize("lighting", ["front", "back"])
def test_cycles_renders_the_exported_growing_look_as_warp_hair(cycles, lighting):
    """`benchmarks/vs_peers.py --growing`, small: a melanin look with color_spread 0.4, roughness_spread 0.25,
    tip_absorption 0.3 and tip_length 0.5 on the draped swatch (64², 256 spp, all bounces), warp-hair against
    Cycles rendering the exported script. The variation changes the image far beyond the noise; Cycles' image
    agrees with ours in its means within 1% and block by block to the noise level (two warp-hair seeds)."""
    bpy, _ = cycles
    sys.path.insert(0, str(BENCHMARKS))
    try:
        from vs_peers import GROWING_LOOKS, LIGHTINGS, draped_swatch, growing_renders, growing_statistics
    finally:
        sys.path.remove(str(BENCHMARKS))
    look = GROWING_LOOKS["melanin"]
    images = growing_renders(bpy, draped_swatch(24), look, LIGHTINGS[lighting], 64, 256, threads=2, baseline=False)
    figures = growing_statistics(images)
    assert figures["variation"] > 4.0 * figures["noise"]
    np.testing.assert_allclose(figures["ratio"], 1.0, atol=0.01)
    assert figures["rmse"] < 1.25 * figures["noise"]
