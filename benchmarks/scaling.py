"""Benchmark: how a forward render's time grows with pixels, samples per pixel, path depth and fiber segments
(10³ to 10⁶), with the BVH build's time and memory per segment.

    python benchmarks/scaling.py [--threads N] [--quick] [--numpy-build] [--out docs]

Writes OUT/scaling.md (the tables) and OUT/scaling.png (log-log plots), and prints the tables.

* pixels, spp, depth: the standard swatch (benchmarks/standard_swatch.toml: 5120 segments, a directional light
  and a constant environment), one parameter varied from 128×128, 8 spp, depth 16 (Russian roulette from
  bounce 8, the scene's default).
* segments: a draped wavy swatch in the same view at every size (brown_wavy's shape, 40 segments per strand),
  filled with more and thinner strands from 10³ to 10⁶ segments (√(strands / 10) layers, the spacing 3 radii:
  the same volume, ever more finely), and issue 24's 10⁵-strand groom (10⁶ segments, 10 a strand), whose render
  the last line holds to 10⁴ segments' times their SAH cost ratio; 128×128, 8 spp, depth 16. Each size runs in
  its own process, so that its peak resident memory (ru_maxrss: the interpreter, Warp and the kernels included,
  about 0.2 GiB) is its own; "BVH bytes" is what the render reads (nodes, tubes, segment and strand indices),
  "SAH" the tree's surface area heuristic cost (node visits at cost
  1 plus tube tests, each weighted by its box's area over the root's: the expected work of a ray through the
  root, lower is better). With --numpy-build the NumPy reference build (tests/helpers/reference_bvh.py,
  the same tree) is timed on the same boxes too.

The scene is prepared once (`prepare`) before a render is timed; preparation (tube frames and boxes, the BVH
build, the arrays) is timed on its own. Times are wall-clock and CPU (time.process_time: all threads of the
process) seconds; on a shared machine other jobs inflate the wall times much more than the CPU times.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

HERE = Path(__file__).resolve().parent
SWATCH = HERE / "standard_swatch.toml"
BASE = {"resolution": 128, "spp": 8, "depth": 16}
SWEEPS = {
    "resolution": (32, 64, 128, 256, 512),
    "spp": (1, 2, 4, 8, 16, 32),
    "depth": (1, 2, 4, 8, 16, 32),
}
SEGMENTS_PER_STRAND = 40
# (segments, segments per strand); the last is issue 24's 10⁵-strand groom: 10⁶ segments of 10 per strand.
SEGMENTS = ((1_000, 40), (10_000, 40), (100_000, 40), (1_000_000, 40), (1_000_000, 10))
QUICK_SEGMENTS = SEGMENTS[:3]
SWATCH_WIDTH = 0.4


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def with_settings(scene, resolution, depth):
    scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, max_depth=depth))
    scene.camera = dataclasses.replace(scene.camera, resolution=(resolution, resolution))
    return scene


def sweep_swatch(threads) -> list:
    """[(parameter, value, wall s, cpu s, rays)] of the standard swatch's renders, one parameter varied at a time."""
    from warp_hair.renderer.prepare import prepare
    from warp_hair.renderer.render import render
    from warp_hair.scene import load_scene

    swatch = load_scene(SWATCH)
    render(with_settings(swatch, 8, 2), spp=1, threads=threads)  # compile or load the kernels
    jobs = [(name, value) for name, values in SWEEPS.items() for value in values]
    rows = []
    for name, value in tqdm(jobs, desc="swatch sweeps", unit="render"):
        settings = {**BASE, name: value}
        prepared = prepare(with_settings(swatch, settings["resolution"], settings["depth"]))
        _, wall, cpu = timed(lambda prepared=prepared, spp=settings["spp"]: render(prepared, spp=spp, threads=threads))
        rows.append((name, value, wall, cpu))
    return rows


def draped_swatch(segments: int, per_strand: int = SEGMENTS_PER_STRAND):
    """The segments sweep's scene: `segments` segments (rounded to whole strands of `per_strand`) in brown_wavy's
    view."""
    from warp_hair.scene import scene_from_dict

    strands = max(4, round(segments / per_strand))
    # Layers and strands per layer both grow as √strands, the spacing shrinks as 1/√strands: the swatch fills
    # the same volume (about 0.4 × 0.5 × 0.04) ever more finely.
    layers = max(2, round(math.sqrt(strands / 10)))
    spacing = SWATCH_WIDTH / (strands / layers)
    return scene_from_dict(
        {
            "camera": {
                "type": "orthographic",
                "origin": [0.0, 0.0, 3.0],
                "target": [0.0, 0.0, 0.0],
                "up": [0.0, 1.0, 0.0],
                "width": 0.5,
                "resolution": [BASE["resolution"]] * 2,
            },
            "lights": [
                {"type": "directional", "direction": [0.2, -0.3, -1.0], "irradiance": [3.0, 3.0, 3.0]},
                {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
            ],
            "fibers": {
                "generator": "wavy",
                "count": strands,
                "layers": layers,
                "length": 0.5,
                "drape": 0.25,
                "width": SWATCH_WIDTH,
                "radius": spacing / 3,
                "amplitude": 0.01,
                "wavelength": 0.15,
                "segments": per_strand,
                "seed": 12,
            },
            "hair": {"albedo": [0.45, 0.28, 0.15], "beta_m": 0.3, "beta_n": 0.4},
            "render": {"spp": BASE["spp"], "max_depth": BASE["depth"], "seed": 1},
        }
    )


def sah_cost(nodes: np.ndarray) -> float:
    """The surface area heuristic cost of the fiber BVH (its BvhNode records, any width), relative to its root box."""
    from warp_hair.geometry.bvh import TRAVERSAL_COST, leaf_range

    bounds = nodes["bounds"].transpose(0, 2, 1).astype(np.float64)  # (N, children, lo xyz + hi xyz)
    lo, hi = bounds[..., :3], bounds[..., 3:]
    child = nodes["child"].astype(np.int64)
    d = hi - lo
    area = d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]
    _, count = leaf_range(np.minimum(child, -1))
    used = (child >= 0) | (count > 0)
    root = np.maximum(hi[0][used[0]].max(axis=0) - lo[0][used[0]].min(axis=0), 0.0)
    root_area = root[0] * root[1] + root[1] * root[2] + root[2] * root[0]
    cost = np.where(child >= 0, TRAVERSAL_COST, count) * np.where(used, area, 0.0)
    return float(TRAVERSAL_COST + cost.sum() / root_area)


def segments_case(segments: int, per_strand: int, threads, numpy_build: bool) -> dict:
    """One size of the segments sweep, in this process: preparation, BVH size and cost, render time, peak memory."""
    import warp as wp

    from warp_hair.renderer.prepare import prepare
    from warp_hair.renderer.render import render

    wp.init()
    render(draped_swatch(1000), spp=1, threads=threads)  # compile or load the kernels
    scene = draped_swatch(segments, per_strand)
    prepared, prep_wall, prep_cpu = timed(lambda: prepare(scene))
    g = prepared.bvh.geometry
    nbytes = sum(a.capacity for a in (g.nodes, g.tubes, g.segment, g.strand))
    _, wall, cpu = timed(lambda: render(prepared, spp=BASE["spp"], threads=threads))
    out = {
        "segments": g.num_segments,
        "strands": scene.fibers.num_strands,
        "per_strand": per_strand,
        "prepare_wall": prep_wall,
        "prepare_cpu": prep_cpu,
        "bvh_bytes": nbytes,
        "sah": sah_cost(g.nodes.numpy()),
        "render_wall": wall,
        "render_cpu": cpu,
        "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    }
    if numpy_build:
        out.update(build_times(scene, threads))
    return out


def build_times(scene, threads) -> dict:
    """CPU seconds of the BVH build alone, in Warp kernels and in the NumPy reference, on the scene's tube boxes."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from helpers import reference_bvh

    from warp_hair.geometry.bvh import TRAVERSAL_COST, build_bvh
    from warp_hair.geometry.tubes import MAX_LEAF, segment_boxes, segment_frames

    p0, p1, r0, r1, strand, _ = scene.fibers.segments()
    lowers, uppers = segment_boxes(segment_frames(p0, p1, r0, r1, strand))
    _, _, warp_cpu = timed(lambda: build_bvh(lowers, uppers, max_leaf=MAX_LEAF, width=4, threads=threads))
    _, _, numpy_cpu = timed(lambda: reference_bvh.build_binary(lowers, uppers, MAX_LEAF, TRAVERSAL_COST))
    return {"build_warp_cpu": warp_cpu, "build_numpy_cpu": numpy_cpu}


def sweep_segments(sizes, threads, numpy_build) -> list:
    rows = []
    for segments, per_strand in tqdm(sizes, desc="segments sweep", unit="size"):
        command = [sys.executable, __file__, "--segments-case", str(segments), str(per_strand)]
        command += ["--numpy-build"] * numpy_build
        if threads:
            command += ["--threads", str(threads)]
        result = subprocess.run(command, capture_output=True, text=True, check=True)
        rows.append(json.loads(result.stdout.strip().splitlines()[-1]))
    return rows


def tables(swatch_rows, segment_rows, threads) -> str:
    base = ", ".join(f"{k} {v}" for k, v in BASE.items())
    lines = [f"Threads: {threads}. Wall and CPU seconds (all threads); the machine may have been shared.", ""]
    for name in SWEEPS:
        lines += [
            f"### Standard swatch, {name} varied (else {base})",
            "",
            f"| {name} | wall s | CPU s | CPU µs per sample |",
            "|---:|---:|---:|---:|",
        ]
        for param, value, wall, cpu in swatch_rows:
            if param == name:
                settings = {**BASE, name: value}
                samples = settings["resolution"] ** 2 * settings["spp"]
                lines.append(f"| {value} | {wall:.3f} | {cpu:.3f} | {cpu / samples * 1e6:.2f} |")
        lines.append("")
    numpy_build = segment_rows and "build_numpy_cpu" in segment_rows[0]
    extra = " BVH build CPU µs/segment: Warp, NumPy |" if numpy_build else ""
    lines += [
        f"### Draped wavy swatch, segments varied ({BASE['resolution']}×{BASE['resolution']}, {BASE['spp']} spp, "
        f"depth {BASE['depth']})",
        "",
        "| segments | strands | prepare wall s | prepare CPU µs/segment | BVH bytes/segment | SAH | peak RSS MiB | "
        "render wall s | render CPU s |" + extra,
        "|---:" * (9 + bool(numpy_build)) + "|",
    ]
    for r in segment_rows:
        m = r["segments"]
        line = (
            f"| {m} | {r['strands']} | {r['prepare_wall']:.3f} | {r['prepare_cpu'] / m * 1e6:.2f} | "
            f"{r['bvh_bytes'] / m:.0f} | "
            f"{r['sah']:.1f} | {r['peak_rss'] / 2**20:.0f} | {r['render_wall']:.3f} | {r['render_cpu']:.3f} |"
        )
        if numpy_build:
            line += f" {r['build_warp_cpu'] / m * 1e6:.2f}, {r['build_numpy_cpu'] / m * 1e6:.2f} |"
        lines.append(line)
    lines += ["", groom_goal(segment_rows)]
    return "\n".join(lines) + "\n"


def groom_goal(segment_rows) -> str:
    """Issue 24's goal for the 10⁵-strand groom: its render no slower per sample than 10⁴ segments' times the ratio
    of their SAH costs (the same image size and samples, so render CPU seconds compare as they are)."""
    base = next((r for r in segment_rows if r["segments"] == 10_000), None)
    groom = next((r for r in segment_rows if r["strands"] >= 100_000), None)
    if base is None or groom is None:
        return "The 10⁵-strand groom is not in this sweep (--quick)."
    time_ratio = groom["render_cpu"] / base["render_cpu"]
    sah_ratio = groom["sah"] / base["sah"]
    verdict = "met" if time_ratio <= sah_ratio else "not met"
    return (
        f"The {groom['strands']}-strand groom ({groom['segments']} segments) renders in {time_ratio:.2f}× the CPU time "
        f"of {base['segments']} segments, where the SAH cost ratio is {sah_ratio:.2f}×: issue 24's goal (at most the "
        f"SAH ratio) {verdict}."
    )


def plot(swatch_rows, segment_rows, path: Path) -> None:
    segment_rows = [r for r in segment_rows if r["per_strand"] == SEGMENTS_PER_STRAND]  # one curve: one strand shape
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    for ax, name in zip(axes, SWEEPS):
        rows = [r for r in swatch_rows if r[0] == name]
        x = np.array([r[1] ** 2 if name == "resolution" else r[1] for r in rows], dtype=float)
        for k, label in ((2, "wall"), (3, "CPU")):
            ax.loglog(x, [r[k] for r in rows], "o-", label=label)
        ax.loglog(x, rows[0][3] * x / x[0], ":", color="grey", label="∝ x")
        ax.set_xlabel({"resolution": "pixels", "spp": "samples per pixel", "depth": "max depth"}[name])
        ax.set_title(f"standard swatch: {name}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("render seconds")
    axes[0].legend()
    ax = axes[3]
    m = np.array([r["segments"] for r in segment_rows], dtype=float)
    ax.loglog(m, [r["render_cpu"] for r in segment_rows], "o-", label="render CPU s")
    ax.loglog(m, [r["prepare_cpu"] for r in segment_rows], "s-", label="prepare (BVH) CPU s")
    ax.loglog(m, [r["peak_rss"] / 2**30 for r in segment_rows], "^-", label="peak RSS GiB")
    ax.set_xlabel("segments")
    ax.set_title("draped swatch: segments")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--quick", action="store_true", help="segments up to 10⁵ only")
    parser.add_argument("--out", type=Path, default=HERE.parent / "docs")
    parser.add_argument(
        "--numpy-build",
        action="store_true",
        help="also time the NumPy reference BVH build (tests/helpers/reference_bvh.py; slow at 10⁶ segments)",
    )
    parser.add_argument("--segments-case", type=int, nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.segments_case:
        print(json.dumps(segments_case(*args.segments_case, args.threads, args.numpy_build)))
        return
    from warp_hair.parallel import default_threads

    threads = args.threads or default_threads()
    swatch_rows = sweep_swatch(threads)
    segment_rows = sweep_segments(QUICK_SEGMENTS if args.quick else SEGMENTS, threads, args.numpy_build)
    text = tables(swatch_rows, segment_rows, threads)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling.md").write_text(
        "# Forward render scaling\n\nMade by `python benchmarks/scaling.py`.\n\n" + text
    )
    plot(swatch_rows, segment_rows, args.out / "scaling.png")
    print(f"wrote {args.out / 'scaling.md'} and {args.out / 'scaling.png'}")


if __name__ == "__main__":
    main()
