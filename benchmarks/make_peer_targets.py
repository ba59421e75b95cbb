"""Render the shipped targets that another renderer makes: Blender Cycles or Mitsuba 3 (target.toml `renderer`).

    python benchmarks/make_peer_targets.py [NAME ...] [--threads N]

Each image is rendered by that renderer from the target's scene file, at its [render] spp and seed, with the
look as `warp_hair.export` writes it for that renderer; truth.json is written from the [hair] table. The fibers
are the scene's own (its generator or file), handed to Cycles as THICK Catmull-Rom curves through the vertices
(benchmarks/cycles_peer.py), and to Mitsuba as a `bsplinecurve` over the vertices with an end control point
mirrored at each end, so that the curve reaches the end vertices (benchmarks/mitsuba_peer.py explains why). The
strands are dense (a segment turns the tangent by well under a degree), so that the polyline warp-hair
renders and the curves the peers render describe the same fibers. Mitsuba's targets have α = 0: its curve
shapes flip the frame's tangent with the side of the fiber that is hit, which would turn the tilt around on
half of each fiber. Mitsuba's images are rendered with its hair sampler's residual lobe corrected
(`mitsuba_peer.CorrectedHair`: Mitsuba 3.9.1 draws that lobe in the normal plane only, which makes light hair
about 2% brighter front-lit); `--mitsuba-sampler stock` renders them with Mitsuba as shipped. Cycles needs the
`blender` extra, Mitsuba the `bench` extra and libLLVM.

A Cycles target with a `cycles_hair.toml` beside its target.toml is rendered with Cycles' own Principled Hair
inputs set directly, not the exported look (issue 44: Cycles' melanin with its Random Color and Random
Roughness, which the exporter does not write):

    parametrization = "MELANIN"
    [inputs]                       # Blender's socket names and units (Offset in radians)
    Melanin = 0.6
    "Melanin Redness" = 0.35
    ...

The scenes' [hair] must be what those inputs are in warp-hair's controls (`cycles_peer.melanin_controls`; an
error gives the table to write otherwise). Where a scene draws its strands as `curve = "catmull-rom"`, Cycles
gets the vertices the curve passes through, and draws its own Catmull-Rom curve (the same one) through them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import tomllib
from pathlib import Path

from cycles_peer import import_bpy, melanin_controls, render_cycles
from mitsuba_peer import SAMPLERS, bspline_control_points, import_mitsuba, mitsuba_scene, time_mitsuba

from optimize.target import SHIPPED_TARGETS, TRUTH_FILE, read_target_spec, target_renderer
from warp_hair.geometry.formats import save_fibers
from warp_hair.io import write_exr
from warp_hair.model.params import HairParams
from warp_hair.parallel import default_threads
from warp_hair.scene import CURVE_OPTIONS, load_scene, scene_from_dict

# Cycles' own Principled Hair inputs for a target (module docstring).
CYCLES_NODE_FILE = "cycles_hair.toml"


def cycles_node(directory):
    """The target's cycles_hair.toml as render_cycles' `node`, or None where it has none."""
    path = Path(directory) / CYCLES_NODE_FILE
    if not path.is_file():
        return None
    node = tomllib.loads(path.read_text(encoding="utf-8"))
    if set(node) != {"parametrization", "inputs"}:
        raise ValueError(f"{path}: needs exactly parametrization = ... and an [inputs] table, got {sorted(node)}")
    return node


def check_node_look(node, scene, where):
    """The scene's [hair] must be the node's look in warp-hair's controls (to 1e-12): else a ValueError that
    gives the [hair] table to write."""
    controls = melanin_controls(node)
    expected = HairParams.from_dict(controls, where=f"{CYCLES_NODE_FILE}'s look").to_dict()
    given = scene.hair.to_dict()
    if set(given) != set(expected) or any(
        not math.isclose(given[k], v, rel_tol=1e-12, abs_tol=1e-15) for k, v in expected.items()
    ):
        table = "\n".join(f"{k} = {v!r}" for k, v in controls.items())
        raise ValueError(f"{where}: its [hair] is not {CYCLES_NODE_FILE}'s look; write\n[hair]\n{table}")


def curve_vertices(scene):
    """The strands whose vertices Cycles draws its Catmull-Rom curves through: the scene's, or, where the scene
    draws them as `curve = "catmull-rom"` (the same curve), the vertices its file or generator gives."""
    fibers = scene.source.get("fibers", {})
    if fibers.get("curve", "polyline") == "polyline":
        return scene.fibers
    source = {**scene.source, "fibers": {k: v for k, v in fibers.items() if k not in CURVE_OPTIONS}}
    return scene_from_dict(source, where=f"{scene.path} (the curves' vertices)").fibers


def peer_renderer(name, mitsuba_sampler="corrected"):
    """(render(scene, threads, node) -> image, version string) for "cycles" or "mitsuba"; exits with the reason
    if missing. `node`: Cycles' own Principled Hair inputs (cycles_hair.toml), or None: the look as exported."""
    if name == "cycles":
        bpy = import_bpy()
        if bpy is None:
            sys.exit(1)

        def render_with_cycles(scene, threads, node=None):
            fibers = curve_vertices(scene)
            return render_cycles(
                bpy, scene, scene.render.spp, threads=threads, seed=scene.render.seed, fibers=fibers, node=node
            )

        return render_with_cycles, f"Cycles {bpy.app.version_string}"
    mi = import_mitsuba()
    if mi is None:
        sys.exit(1)

    def render_mitsuba(scene, threads, node=None):
        if node is not None:
            raise ValueError(f"{CYCLES_NODE_FILE} is Cycles' material; Mitsuba renders the exported look")
        if scene.hair.alpha != 0.0:
            raise ValueError("Mitsuba's targets need alpha = 0 (its curves flip the tangent with the side hit)")
        with tempfile.TemporaryDirectory() as tmp:
            fibers_file = Path(tmp) / "fibers.txt"
            save_fibers(bspline_control_points(scene.fibers), fibers_file)
            mi_scene = mitsuba_scene(
                mi, scene, scene.render.spp, shape="bsplinecurve", fibers_file=fibers_file, sampler=mitsuba_sampler
            )
            return time_mitsuba(mi, mi_scene, scene.render.spp, scene.render.seed, threads, 1)[2]

    return render_mitsuba, f"Mitsuba {mi.__version__} ({mi.variant()}, bsplinecurve, {mitsuba_sampler} hair sampler)"


def make_peer_target(directory, threads, mitsuba_sampler="corrected"):
    renderer = target_renderer(directory)
    node = cycles_node(directory)
    render, version = peer_renderer(renderer, mitsuba_sampler)
    hair = None
    for entry in read_target_spec(directory):
        scene = load_scene(directory / entry["scene"])
        if node is not None:
            check_node_look(node, scene, directory / entry["scene"])
        start = time.perf_counter()
        image = render(scene, threads, node)
        meta = {
            "renderer": version,
            "scene": entry["scene"],
            "spp": scene.render.spp,
            "seed": scene.render.seed,
            "hair": scene.hair.to_dict(),
        }
        if node is not None:
            meta["cycles_hair"] = node
        write_exr(directory / entry["image"], image, {"warp_hair": meta})
        print(
            f"{directory.name}/{entry['image']}: {version}, {scene.render.spp} spp, {time.perf_counter() - start:.0f} s"
        )
        hair = scene.hair
    # As `warp-hair targets make` writes it: a uniform look's leaves the variation's controls out.
    (directory / TRUTH_FILE).write_text(json.dumps(hair.to_table(), indent=2) + "\n", encoding="utf-8")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="target names (default: every shipped target a peer renders)")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument(
        "--mitsuba-sampler",
        choices=SAMPLERS,
        default="corrected",
        help="Mitsuba's hair sampler as shipped, or with its residual lobe corrected (default)",
    )
    args = parser.parse_args(argv)
    names = args.names or sorted(
        p.name for p in SHIPPED_TARGETS.iterdir() if (p / "target.toml").is_file() and target_renderer(p) != "warp-hair"
    )
    for name in names:
        try:
            make_peer_target(SHIPPED_TARGETS / name, args.threads or default_threads(), args.mitsuba_sampler)
        except ValueError as error:  # a scene that disagrees with its files: the message says what to write
            parser.exit(2, f"make_peer_targets: {name}: {error}\n")


if __name__ == "__main__":
    main()
