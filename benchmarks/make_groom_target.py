"""A production-sized groom as a Cycles target: 10⁴ wavy, clumped strands on a scalp-like patch, as USD.

    python benchmarks/make_groom_target.py [--out benchmarks/out/groom_target] [--count 10000] [--seed 23]
                                           [--resolution 96] [--spp 256] [--threads N] [--no-render]
    python benchmarks/make_groom_target.py --compare 128     # warp-hair at the truth against the Cycles images
    warp-hair fit benchmarks/out/groom_target -o OUT [--refine 24]

Makes, in --out, what a groom artist would bring from their own pipeline and a target directory of it:
- `groom.usdc`: the groom as one `UsdGeom.BasisCurves` prim (/Groom/hair; cubic, catmullRom, nonperiodic, each
  strand's end points written twice so that the curve runs from root to tip as Cycles draws it; `vertex` widths;
  Y up). Deterministic for a seed (4 MB at 10⁴ strands of 32 spans, so it is made here, not shipped).
  The groom: roots uniform on a spherical cap (the front of the crown of a head of radius 0.3, 30° across in
  each direction from its centre) leave along the scalp's normal and turn to hang down over an arc length of about
  0.12, wave (amplitude 0.006, wavelength 0.2, each clump in its own phase) and gather into 150 clumps toward the
  tips, each strand pulled 60% of the way onto its clump's guide at the tip: neighbours pass through each other,
  as a simulated groom's do. Radius 0.0012 at the root to 0.0006 at the tip; lengths 0.45 ± 10%.
- `sky.exr`: benchmarks/synthetic_sky.py's lat-long map (a sun disc off every axis over coloured gradients).
- `scene_front.toml`, `scene_back.toml`: two perspective cameras on the groom, one on the sun's side (front-lit),
  one opposite (the sun behind the hair), lit by the map only; `interpenetration = "exit"` (Cycles 4.x's CPU
  rule, docs/scenes.md), the fibers read from the USD file.
- `front.exr`, `back.exr`: rendered by Cycles (bpy 4.5) from the same USD, imported by Blender's own USD
  importer (`bpy.ops.wm.usd_import`), with the look as `warp-hair export --to cycles` writes it, under the same
  map (benchmarks/cycles_peer.py); `target.toml` and `truth.json`.
Timings are wall-clock on whatever else the machine is doing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from cycles_peer import import_bpy, render_cycles
from synthetic_sky import synthetic_sky

from warp_hair.geometry.interpenetration import interpenetration
from warp_hair.io import write_exr
from warp_hair.parallel import default_threads
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
HAIR = {"albedo": [0.42, 0.28, 0.17], "beta_m": 0.28, "beta_n": 0.38, "alpha": 2.0, "eta": 1.55}
SUN = (-0.35, 0.45, 0.82)  # toward the sun: up, to the left, in front of the face
HEAD_RADIUS = 0.3
CAP_CENTRE = (0.0, 0.55, 0.835)  # the front of the crown
CAP_ANGLE = 30.0  # degrees from the cap's centre to its edge
CLUMPS = 150
CLUMPING = 0.6  # how far a tip moves onto its clump's guide
LENGTH, LENGTH_JITTER = 0.45, 0.1
ROOT_RADIUS, TIP_RADIUS = 0.0012, 0.0006
AMPLITUDE, WAVELENGTH = 0.006, 0.2
FALL = 0.12  # arc length over which a strand turns from the scalp's normal to hanging down
LOOK_AT = (0.0, -0.02, 0.36)
CAMERAS = {
    # (origin, horizontal field of view in degrees): the front camera on the sun's side, the back one opposite.
    "front": ((0.45, 0.25, 2.4), 20.0),
    "back": ((-0.35, 0.05, -1.9), 21.0),
}


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cap_points(count, rng):
    """Unit directions uniform (by area) on the cap of half-angle CAP_ANGLE around CAP_CENTRE."""
    cos_max = np.cos(np.radians(CAP_ANGLE))
    cos_t = rng.uniform(cos_max, 1.0, count)
    phi = rng.uniform(0.0, 2.0 * np.pi, count)
    sin_t = np.sqrt(1.0 - cos_t**2)
    c = _unit(CAP_CENTRE)
    a = _unit(np.cross(c, [1.0, 0.0, 0.0]))
    b = np.cross(c, a)
    return cos_t[:, None] * c + sin_t[:, None] * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)


def _grow(normals, lengths, phases, segments):
    """Strand vertices (S, segments + 1, 3), roots at HEAD_RADIUS × normals: along the normal, turning to hang
    down over FALL, waving across the fall (amplitude growing in over the first FALL of arc length)."""
    s = np.linspace(0.0, 1.0, segments + 1)[None, :] * lengths[:, None]  # arc length (S, N)
    turn = 1.0 - np.exp(-s / FALL)
    down = np.array([0.0, -1.0, 0.0])
    # The direction at each arc length; integrate it with the midpoint rule.
    mid = 0.5 * (s[:, 1:] + s[:, :-1])
    w = (1.0 - np.exp(-mid / FALL))[..., None]
    direction = _unit((1.0 - w) * normals[:, None, :] + w * down)
    steps = direction * np.diff(s, axis=1)[..., None]
    axis = HEAD_RADIUS * normals[:, None, :] + np.concatenate([np.zeros_like(steps[:, :1]), np.cumsum(steps, 1)], 1)
    # Wave across the fall: along x mostly, some along z, so the strands are 3-D waves, not flat ones.
    angle = 2.0 * np.pi * s / WAVELENGTH + phases[:, None]
    wave = AMPLITUDE * turn[..., None] * np.stack([np.sin(angle), np.zeros_like(angle), 0.5 * np.cos(angle)], -1)
    return axis + wave


def groom(count=10_000, seed=23, segments=32):
    """(points (S, segments + 1, 3), radii (S, segments + 1)) of the groom in the module docstring."""
    rng = np.random.default_rng(seed)
    normals = _cap_points(count, rng)
    centres = _cap_points(CLUMPS, rng)
    clump = np.argmax(normals @ centres.T, axis=1)  # the nearest clump centre on the sphere
    lengths = LENGTH * (1.0 + LENGTH_JITTER * rng.uniform(-1.0, 1.0, count))
    clump_phase = rng.uniform(0.0, 2.0 * np.pi, CLUMPS)
    phases = clump_phase[clump] + rng.normal(0.0, 0.4, count)
    strands = _grow(normals, lengths, phases, segments)
    guides = _grow(centres, np.full(CLUMPS, LENGTH), clump_phase, segments)[clump]
    # Clumping pulls a strand toward its guide at the same fraction of its length, more toward the tip.
    pull = CLUMPING * np.linspace(0.0, 1.0, segments + 1)[None, :, None] ** 1.5
    points = strands + pull * (guides - strands)
    radii = np.broadcast_to(np.linspace(ROOT_RADIUS, TIP_RADIUS, segments + 1), (count, segments + 1))
    return points.astype(np.float32), np.ascontiguousarray(radii, dtype=np.float32)


def write_groom_usd(points, radii, path):
    """One catmullRom BasisCurves prim, /Groom/hair, Y up, each strand's end points doubled (the curve then
    spans root to tip, the phantom end points being the ends themselves, as Cycles draws a curve)."""
    from pxr import Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    root = UsdGeom.Xform.Define(stage, "/Groom")
    stage.SetDefaultPrim(root.GetPrim())
    curves = UsdGeom.BasisCurves.Define(stage, "/Groom/hair")
    curves.CreateTypeAttr(UsdGeom.Tokens.cubic)
    curves.CreateBasisAttr(UsdGeom.Tokens.catmullRom)
    curves.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
    doubled = np.concatenate([points[:, :1], points, points[:, -1:]], axis=1)
    widths = 2.0 * np.concatenate([radii[:, :1], radii, radii[:, -1:]], axis=1)
    curves.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(doubled.reshape(-1, 3))))
    curves.CreateCurveVertexCountsAttr(Vt.IntArray([doubled.shape[1]] * doubled.shape[0]))
    curves.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.ascontiguousarray(widths.ravel())))
    curves.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    stage.GetRootLayer().Export(str(path))


def scene_text(view, resolution, spp):
    origin, fov = CAMERAS[view]
    lit = "front-lit: the camera on the sun's side" if view == "front" else "back-lit: the sun behind the hair"
    hair = "\n".join(f"{k} = {json.dumps(v)}" for k, v in HAIR.items())
    return f"""# A groom of 10^4 wavy, clumped strands whose neighbours pass through each other, under an HDRI; {lit}.
# Made and rendered by Blender Cycles 4.5 from groom.usdc: `python benchmarks/make_groom_target.py`.
[camera]
type = "perspective"
origin = {list(origin)}
target = {list(LOOK_AT)}
up = [0.0, 1.0, 0.0]
fov = {fov}
resolution = [{resolution}, {resolution}]

[[lights]]
type = "environment"
file = "sky.exr"

[fibers]
file = "groom.usdc"
tolerance = 0.1

[hair]
{hair}

[render]
spp = {spp}
max_depth = 64
seed = 1
# The strands interpenetrate: render as Cycles 4.x does on the CPU (docs/scenes.md, "Interpenetrating strands").
interpenetration = "exit"
"""


TARGET_TOML = """# A groom of 10^4 wavy, clumped, interpenetrating strands (groom.usdc) under a synthetic HDRI,
# rendered by Blender Cycles 4.5 from the USD: `python benchmarks/make_groom_target.py` makes this directory.
renderer = "cycles"

[[images]]
scene = "scene_front.toml"
image = "front.exr"

[[images]]
scene = "scene_back.toml"
image = "back.exr"
"""


def compare(out, spp, threads):
    """warp-hair at the truth against the target's Cycles images: channel means, 8×8-block RMSE, two seeds' noise."""
    from vs_peers import block_rmse, fmt

    from warp_hair.io import read_exr
    from warp_hair.renderer.render import render

    for view in CAMERAS:
        scene = load_scene(out / f"scene_{view}.toml")
        cycles, _ = read_exr(out / f"{view}.exr")
        images = []
        for seed in (0, 1):
            scene = dataclasses.replace(scene, render=dataclasses.replace(scene.render, spp=spp, seed=seed))
            start = time.perf_counter()
            images.append(render(scene, threads=threads))
            print(f"[{view}] warp-hair, {spp} spp, seed {seed}: {time.perf_counter() - start:.0f} s")
        ours = images[0]
        write_exr(out.parent / f"groom_warp_hair_{view}.exr", ours)
        ratio = ours.mean(axis=(0, 1)) / cycles.mean(axis=(0, 1))
        print(
            f"[{view}] warp-hair / Cycles: means {fmt(ours.mean(axis=(0, 1)))} / {fmt(cycles.mean(axis=(0, 1)))} = "
            f"{fmt(ratio)}; block RMSE {block_rmse(ours, cycles):.2%} (two warp-hair seeds at {spp} spp: "
            f"{block_rmse(images[1], ours):.2%})"
        )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE / "out" / "groom_target")
    parser.add_argument("--count", type=int, default=10_000)
    parser.add_argument("--segments", type=int, default=32, help="Catmull-Rom spans per strand")
    parser.add_argument("--seed", type=int, default=23)
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--spp", type=int, default=256, help="Cycles' samples per pixel")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--no-render", action="store_true", help="write the USD, map and scene files only")
    parser.add_argument(
        "--compare",
        type=int,
        metavar="SPP",
        help="render the made target in warp-hair at its truth (SPP samples) "
        "and print how it agrees with Cycles' images; makes nothing",
    )
    args = parser.parse_args(argv)
    out = args.out
    if args.compare:
        return compare(out, args.compare, args.threads or default_threads())
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    points, radii = groom(args.count, args.seed, args.segments)
    write_groom_usd(points, radii, out / "groom.usdc")
    print(
        f"groom.usdc: {args.count} strands x {args.segments} spans, "
        f"{(out / 'groom.usdc').stat().st_size / 2**20:.1f} MB, {time.perf_counter() - start:.1f} s"
    )
    write_exr(out / "sky.exr", synthetic_sky(sun=SUN))
    for view in CAMERAS:
        (out / f"scene_{view}.toml").write_text(scene_text(view, args.resolution, args.spp), encoding="utf-8")
    (out / "target.toml").write_text(TARGET_TOML, encoding="utf-8")
    (out / "truth.json").write_text(json.dumps(HAIR, indent=2) + "\n", encoding="utf-8")
    scene = load_scene(out / "scene_front.toml")
    print(
        f"warp-hair reads {scene.fibers.num_strands} strands, {scene.fibers.num_segments} segments (tolerance 0.1 "
        f"radii); check: {interpenetration(scene.fibers).message('exit')}"
    )
    if args.no_render:
        return
    bpy = import_bpy()
    if bpy is None:
        raise SystemExit(1)
    threads = args.threads or default_threads()
    for view in CAMERAS:
        scene = load_scene(out / f"scene_{view}.toml")
        start = time.perf_counter()
        spp, seed = scene.render.spp, scene.render.seed
        image = render_cycles(bpy, scene, spp, threads=threads, seed=seed, usd=out / "groom.usdc")
        version = f"Cycles {bpy.app.version_string}"
        meta = {"renderer": version, "scene": f"scene_{view}.toml", "spp": spp, "seed": seed, "hair": HAIR}
        write_exr(out / f"{view}.exr", image, {"warp_hair": meta})
        print(f"{view}.exr: {version}, {spp} spp, {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
