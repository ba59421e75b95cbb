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
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from cycles_peer import import_bpy, render_cycles
from mitsuba_peer import SAMPLERS, bspline_control_points, import_mitsuba, mitsuba_scene, time_mitsuba

from optimize.target import SHIPPED_TARGETS, TRUTH_FILE, read_target_spec, target_renderer
from warp_hair.geometry.formats import save_fibers
from warp_hair.io import write_exr
from warp_hair.parallel import default_threads
from warp_hair.scene import load_scene


def peer_renderer(name, mitsuba_sampler="corrected"):
    """(render(scene) -> image, version string) for "cycles" or "mitsuba"; exits with the reason if missing."""
    if name == "cycles":
        bpy = import_bpy()
        if bpy is None:
            sys.exit(1)
        return (
            lambda scene, threads: render_cycles(bpy, scene, scene.render.spp, threads=threads, seed=scene.render.seed)
        ), f"Cycles {bpy.app.version_string}"
    mi = import_mitsuba()
    if mi is None:
        sys.exit(1)

    def render_mitsuba(scene, threads):
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
    render, version = peer_renderer(renderer, mitsuba_sampler)
    hair = None
    for entry in read_target_spec(directory):
        scene = load_scene(directory / entry["scene"])
        start = time.perf_counter()
        image = render(scene, threads)
        meta = {
            "renderer": version,
            "scene": entry["scene"],
            "spp": scene.render.spp,
            "seed": scene.render.seed,
            "hair": scene.hair.to_dict(),
        }
        write_exr(directory / entry["image"], image, {"warp_hair": meta})
        print(
            f"{directory.name}/{entry['image']}: {version}, {scene.render.spp} spp, {time.perf_counter() - start:.0f} s"
        )
        hair = scene.hair
    (directory / TRUTH_FILE).write_text(json.dumps(hair.to_dict(), indent=2) + "\n", encoding="utf-8")


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
        make_peer_target(SHIPPED_TARGETS / name, args.threads or default_threads(), args.mitsuba_sampler)


if __name__ == "__main__":
    main()
