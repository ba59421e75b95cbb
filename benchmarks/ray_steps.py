"""Benchmark: rays per second per core of each kind, for several versions of the traversal and for Embree, on the
same rays in one run: the clock's side of docs/benchmarks.md's table of issue 24's steps.

    python benchmarks/ray_steps.py [COMMIT ...] [--scene TOML] [--record-spp 1] [--rounds 3]

Records the rays of the scene's paths with this checkout (`profile_render.recorded_rays`: camera rays, a shadow
ray and a continuation a vertex), then times each COMMIT's `rays.intersect` and `rays.occluded` on them, one
process a commit (a `git worktree` of it, its own kernels), on one core as `profile_render.py` does, and Mitsuba
3 (Embree, one thread: `ray_intersect_preliminary` and `ray_test`) on the same rays. The versions and Embree
are alternated `--rounds` times and each cell is the median, because a shared machine's load drifts between
runs. Where a version has `rays.distance` (the preliminary query: distance and segment, as Embree's), its
continuation and camera rays are timed that way too. The rays carry no origin tube, so a step that only skips
the tube a ray leaves does not show here (`ray_instructions.py --render` counts it).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
KINDS = ("camera", "continuation", "shadow")

# Run inside each version's worktree: its own warp_hair, the rays saved by the parent.
CHILD = """
import json, sys, time
import numpy as np
from warp_hair.scene import load_scene
from warp_hair.renderer.prepare import prepare
from warp_hair.geometry import rays as R
bvh = prepare(load_scene(sys.argv[1])).bvh
saved = np.load(sys.argv[2])
out = {}
for kind in ("camera", "continuation", "shadow"):
    o, d = saved[kind + "_o"], saved[kind + "_d"]
    queries = {"occluded": R.occluded} if kind == "shadow" else {"intersect": R.intersect}
    if kind != "shadow" and hasattr(R, "distance"):
        queries["distance"] = R.distance
    for name, trace in queries.items():
        trace(bvh, o[:1000], d[:1000])
        cpu = time.process_time()
        trace(bvh, o, d)
        out[kind + " " + name] = (time.process_time() - cpu) / len(o)
print("RESULT " + json.dumps(out))
"""


def worktree(commit: str, root: Path) -> Path:
    path = root / commit
    subprocess.run(
        ["git", "-C", str(REPO), "worktree", "add", "--detach", "-f", str(path), commit],
        check=True,
        capture_output=True,
    )
    return path


def time_version(tree: Path, scene: Path, saved: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1")
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(scene), str(saved)], cwd=tree, env=env, capture_output=True, text=True
    )
    for line in run.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise SystemExit(f"{tree.name}: no result\n{run.stderr[-3000:]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("commits", nargs="*", default=["HEAD"])
    parser.add_argument("--scene", type=Path, default=HERE / "standard_swatch.toml")
    parser.add_argument("--record-spp", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from profile_render import mitsuba_ray_rates, recorded_rays

    from warp_hair.renderer.prepare import prepare
    from warp_hair.scene import load_scene

    scene_path = args.scene.resolve()
    scene = load_scene(scene_path)
    rays = recorded_rays(prepare(scene), args.record_spp)
    print(f"{scene_path.name}: " + ", ".join(f"{len(rays[k][0])} {k} rays" for k in KINDS), flush=True)
    cells: dict[str, dict[str, list]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        saved = root / "rays.npz"
        np.savez(saved, **{f"{k}_{x}": a for k, (o, d) in rays.items() for x, a in (("o", o), ("d", d))})
        trees = {c: worktree(c, root) for c in args.commits}
        try:
            for r in range(args.rounds):
                for commit, tree in trees.items():
                    for key, value in time_version(tree, scene_path, saved).items():
                        cells.setdefault(commit, {}).setdefault(key, []).append(value)
                for kind, value in mitsuba_ray_rates(scene, rays).items():
                    cells.setdefault("Embree", {}).setdefault(kind, []).append(value)
                print(f"round {r + 1} of {args.rounds} done", flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)
    print(
        "\nµs a ray on one core, median of the rounds (million rays per second per core); "
        "closest hits: full hit / preliminary query"
    )
    print("| version | camera | continuation | shadow |\n| --- | --- | --- | --- |")
    for version, values in cells.items():
        row = []
        for kind in KINDS:
            names = (
                (kind,)
                if version == "Embree"
                else ((f"{kind} occluded",) if kind == "shadow" else (f"{kind} intersect", f"{kind} distance"))
            )
            found = [statistics.median(values[n]) * 1e6 for n in names if n in values]
            row.append(" / ".join(f"{us:.3f} ({1 / us:.2f} M)" for us in found))
        print(f"| {version} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
