"""Benchmark: warp-hair against Mitsuba 3 on draped, non-overlapping swatches, front- and back-lit.

    python benchmarks/vs_peers.py [--spp 256] [--resolution 64] [--segments 24] [--max-depth 100]
                                  [--lightings front,back] [--albedo R G B] [--threads N] [--out DIR]
    python benchmarks/vs_peers.py --alpha 5      # the cuticle tilt's sign against Cycles instead
    python benchmarks/vs_peers.py --interpenetrating [--spp 512]   # strands that pass through each other
    python benchmarks/vs_peers.py --growing [--spp 256]   # hair as it grows, exported to Cycles

The swatch is made here (`warp_hair.geometry.swatch` with `drape`): 4 layers of 38 straight fibers of radius
0.004, 0.5 long, draped over a cylinder of radius 0.25 (2 radians of drape), spaced so that fibers hardly touch
(the interpenetration check finds 2 pairs overlapping by 1.4% of their radii): renderers disagree inside
interpenetrating tubes (docs/scenes.md, "Interpenetrating strands"; `--interpenetrating` below).
The camera looks head-on at the middle of the drape, so the highlight band crosses the image. Lit by a
directional light from the front (or from behind, through the swatch) and a dim constant sky; light-brown hair
(albedo 0.55, 0.40, 0.25, β_m 0.3, β_n 0.35) at α = 0, all bounces (max depth 100).

Mitsuba renders the same strands as a `bsplinecurve` with the polyline's vertices as control points, plus
one mirrored control point at each end so that the curve reaches the end vertices (without them it stops about
a segment short, and the swatch's ends, which shadow and light the visible part, differ); its `linearcurve`
hands the hair BSDF a wrong frame on fibers not along y. At α = 0 (on both of its curve
shapes the frame's tangent flips with the side of the fiber that is hit): see `docs/MODEL.md` or the
project's model notes. warp-hair renders the strands three times: as the polyline with smooth shading tangents
(the default), with each segment's own axis (`[render] tangents = "segment"`), which shows what a polyline's
joints do to the highlight, and as the Catmull-Rom curve through the vertices (`[fibers] curve = "catmull-rom"`,
`warp_hair.geometry.curves`), the curve Cycles draws; on coarse strands (`--segments 6`) only that one is the
same fiber as Cycles'.

Mitsuba renders twice: as shipped (`stock`), and with its hair sampler's residual lobe corrected
(`corrected`, `mitsuba_peer.CorrectedHair`): Mitsuba 3.9.1 samples that lobe in the fiber's normal plane
only (`python benchmarks/mitsuba_residual_lobe.py`), which makes its light hair about 2% brighter front-lit.

Both peers render the look as `warp_hair.export` writes it for them (Mitsuba's `hair` dictionary, the Cycles
bpy script), so this is also the check of the exporters. Cycles (the `blender` extra, bpy 4.5) renders THICK
Catmull-Rom curves through the vertices (benchmarks/cycles_peer.py lists its settings).

For each pair of images it prints the channel means and their ratio, and the RMS relative difference of
8×8-pixel block means against the noise level: the same statistic between two warp-hair renders with
independent seeds (what two renderers that agree exactly would show at this spp, if their noise were alike).
Writes EXRs and `side_by_side_{peer}_{lighting}.png` (ours as the polyline | ours as the Catmull-Rom curve | peer,
all at one exposure | each of ours minus the peer in 8×8 blocks, over the peer's mean: mid grey is no
difference, lighter is ours brighter, ±10% is ±0.2 in linear value) to --out.
Mitsuba needs the `bench` extra (`pip install -e ".[bench]"`) and libLLVM (`apt-get install libllvm19`). A peer
that is not installed is skipped, with the reason.

`--interpenetrating` renders, instead, issue 23's swatch whose strands pass through each other: wavy strands
(amplitude 0.006, wavelength 0.08) with independent phases, 4 layers of 38 at a spacing of 0.0105 (width 0.4),
radius 0.004, 96 segments, draped over a rod of radius 0.25; albedo (0.5, 0.35, 0.25), β_m 0.3, β_n 0.4, α = 0;
lit as the shipped targets are (one directional light, front or back). It prints the interpenetration check,
the fraction of the fibers' surface that lies inside another strand's tube (where every path vertex starts its
continuation and shadow rays inside that tube), and warp-hair as the Catmull-Rom curve under both
`[render] interpenetration` rules, "enter" (the default) and "exit" (as Cycles 4.x on the CPU), against Mitsuba
(bsplinecurve, corrected sampler) and Cycles, with the same statistics; then the table docs/scenes.md
("Interpenetrating strands") shows.

`--growing` checks the export of hair as it grows (model/variation.py) instead: looks with color_spread 0.4,
roughness_spread 0.25, tip_absorption 0.3, tip_length 0.5 (light-brown albedo as above, and a melanin look,
eumelanin 0.5, pheomelanin 0.3), warp-hair rendering the Catmull-Rom curve through the vertices, Cycles the
exported script (Random Roughness, and Math nodes on Hair Info's Random and Intercept). Besides the statistics
above it prints the block RMSE between warp-hair's renders of the look with and without its variation: how
much the variation shows, which the export must reproduce.

`--alpha DEG` checks the tilt's sign instead (Cycles only: Mitsuba's curves flip the tangent with the side of the
fiber hit). The strands run root first from the bottom of the image to the top, so a positive, physical tilt
moves the highlight band down, toward the roots: it prints the band's centroid row (row 0 at the top) in
warp-hair at +α and −α and in Cycles with the exported Offset.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np
from cycles_peer import import_bpy, render_cycles
from mitsuba_peer import SAMPLERS, bspline_control_points, import_mitsuba, mitsuba_scene, time_mitsuba

from warp_hair.geometry.curves import catmull_rom
from warp_hair.geometry.formats import save_fibers
from warp_hair.geometry.generators import swatch, wavy
from warp_hair.geometry.interpenetration import interpenetration, points_inside_other_strands
from warp_hair.io import write_exr, write_png
from warp_hair.parallel import default_threads
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

HERE = Path(__file__).resolve().parent
BLOCK = 8
HAIR = {"albedo": [0.55, 0.4, 0.25], "beta_m": 0.3, "beta_n": 0.35, "alpha": 0.0, "eta": 1.55}
LIGHTINGS = {
    # The direction the light travels: from the front (toward −z, away from the camera) or from behind.
    "front": [0.2, -0.3, -1.0],
    "back": [0.15, -0.25, 1.0],
}


# Issue 23's interpenetrating swatch and its look; lit as the shipped targets are (targets/cycles_*/scene_*.toml).
TANGLED_HAIR = {"albedo": [0.5, 0.35, 0.25], "beta_m": 0.3, "beta_n": 0.4, "alpha": 0.0, "eta": 1.55}
TARGET_LIGHTINGS = {"front": [0.2, -0.3, -1.0], "back": [0.0, -0.15, 1.0]}


def interpenetrating_swatch():
    return wavy(
        count=152,
        layers=4,
        length=0.5,
        radius=0.004,
        width=0.4,
        amplitude=0.006,
        wavelength=0.08,
        phase_jitter=1.0,
        segments=96,
        drape=0.25,
        jitter=0.15,
        seed=23,
    )


def draped_swatch(segments):
    return swatch(count=152, layers=4, length=0.5, radius=0.004, width=0.4, segments=segments, drape=0.25, seed=0)


def scene_data(resolution, light_direction, spp, tangents="smooth", max_depth=100, albedo=None):
    return {
        "camera": {
            "type": "orthographic",
            "origin": [0.0, 0.0, 3.0],
            "target": [0.0, 0.0, -0.05],
            "up": [0.0, 1.0, 0.0],
            "width": 0.36,
            "resolution": [resolution, resolution],
        },
        "lights": [
            {"type": "directional", "direction": light_direction, "irradiance": [3.0, 3.0, 3.0]},
            {"type": "environment", "radiance": [0.05, 0.05, 0.05]},
        ],
        # Replaced by the draped swatch below; the table only has to be valid.
        "fibers": {"generator": "swatch", "count": 1, "layers": 1},
        "hair": HAIR if albedo is None else {**HAIR, "albedo": list(albedo)},
        "render": {"spp": spp, "max_depth": max_depth, "seed": 0, "tangents": tangents},
    }


def blocks(image):
    h, w = (image.shape[0] // BLOCK) * BLOCK, (image.shape[1] // BLOCK) * BLOCK
    return image[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).mean(axis=(1, 3))


def block_rmse(a, b):
    """RMS of the relative difference of block means, over blocks the fibers cover (mean above 1% of the max)."""
    ba, bb = blocks(a), blocks(b)
    lit = bb.mean(axis=2) > 0.01 * bb.mean(axis=2).max()
    return float(np.sqrt(np.mean((ba[lit] / bb[lit] - 1.0) ** 2)))


def fmt(values, spec=".4f"):
    return "(" + ", ".join(format(v, spec) for v in values) + ")"


def highlight_row(image):
    """The centroid row of the brightest fifth of the rows (each row's mean luminance)."""
    profile = image.mean(axis=(1, 2))
    bright = profile >= np.quantile(profile, 0.8)
    rows = np.arange(len(profile))
    return float(np.sum(rows[bright] * profile[bright]) / np.sum(profile[bright]))


def surface_inside_others(fibers, samples=200_000, seed=0):
    """The fraction of the fibers' surface (area-weighted samples on the tubes) inside another strand's tube."""
    rng = np.random.default_rng(seed)
    p0, p1, r0, r1, strand, _ = fibers.segments()
    p0, p1 = p0.astype(np.float64), p1.astype(np.float64)
    radius = (r0 + r1) / 2.0
    axis = p1 - p0
    length = np.linalg.norm(axis, axis=1)
    pick = rng.choice(len(length), samples, p=radius * length / np.sum(radius * length))
    a = axis[pick] / length[pick, None]
    helper = np.where(np.abs(a[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(a, u)
    angle = rng.uniform(0, 2 * np.pi, samples)[:, None]
    along = rng.uniform(0, 1, samples)[:, None]
    points = p0[pick] + along * axis[pick] + radius[pick, None] * (np.cos(angle) * u + np.sin(angle) * v)
    return float(np.mean(points_inside_other_strands(fibers, points, strand[pick])))


def tangled_picture(images, peers):
    """warp-hair "enter" | "exit" | each peer, at the last peer's exposure; then each rule minus that peer in 8×8
    blocks over its mean (mid grey is none, lighter is ours brighter, ±10% is ±0.2), 2× enlarged."""
    reference = list(peers.values())[-1]
    exposure = 0.8 / float(np.percentile(reference, 99.5))
    panels = [exposure * image for image in [*images.values(), *peers.values()]]
    for ours in images.values():
        diff = np.kron((blocks(ours) - blocks(reference)) / reference.mean(), np.ones((BLOCK, BLOCK, 1)))
        pad = ((0, ours.shape[0] - diff.shape[0]), (0, ours.shape[1] - diff.shape[1]), (0, 0))
        panels.append(0.21 + 2.0 * np.pad(diff, pad, constant_values=0.0))
    return np.kron(np.concatenate(panels, axis=1), np.ones((2, 2, 1)))


def interpenetrating_check(args, threads):
    """Issue 23's swatch: warp-hair under both interpenetration rules against Mitsuba and Cycles."""
    fibers = interpenetrating_swatch()
    curve = catmull_rom(fibers)
    report = interpenetration(fibers)
    print(
        f"interpenetrating swatch: {fibers.num_strands} strands x 96 segments, {args.resolution}^2 px, {args.spp} spp"
    )
    print(f"check: {report.message()}")
    print(
        f"fibers' surface inside another strand's tube: {surface_inside_others(fibers):.1%} "
        f"(the Catmull-Rom curve: {surface_inside_others(curve):.1%})"
    )
    mi = import_mitsuba()
    bpy = import_bpy()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        fibers_file = Path(tmp) / "tangled.txt"
        save_fibers(bspline_control_points(fibers), fibers_file)
        for lighting in args.lightings.split(","):
            data = scene_data(args.resolution, TARGET_LIGHTINGS[lighting], args.spp, max_depth=args.max_depth)
            data["lights"] = data["lights"][:1]
            data["hair"] = TANGLED_HAIR
            images = {}
            for rule in ("enter", "exit"):
                data["render"]["interpenetration"] = rule
                scene = scene_from_dict(data)
                scene.fibers = curve
                start = time.perf_counter()
                images[f"warp-hair {rule}"] = render(scene, threads=threads)
                print(f"[{lighting}] warp-hair, interpenetration = {rule}: {time.perf_counter() - start:.1f} s")
            data["render"]["interpenetration"] = "enter"
            noise_scene = scene_from_dict({**data, "render": {**data["render"], "seed": 1}})
            noise_scene.fibers = curve
            noise = block_rmse(render(noise_scene, threads=threads), images["warp-hair enter"])
            scene.fibers = fibers  # the peers draw their own curves through the vertices
            peers = {}
            if mi is not None:
                mi_scene = mitsuba_scene(
                    mi, scene, args.spp, shape="bsplinecurve", fibers_file=fibers_file, sampler="corrected"
                )
                start = time.perf_counter()
                peers[f"Mitsuba {mi.__version__}"] = time_mitsuba(mi, mi_scene, args.spp, 0, threads, 1)[2]
                print(f"[{lighting}] Mitsuba bsplinecurve, corrected sampler: {time.perf_counter() - start:.1f} s")
            if bpy is not None:
                start = time.perf_counter()
                peers[f"Cycles {bpy.app.version_string}"] = render_cycles(bpy, scene, args.spp, threads=threads)
                print(f"[{lighting}] Cycles: {time.perf_counter() - start:.1f} s")
            for name, image in {**images, **peers}.items():
                write_exr(args.out / f"tangled_{name.replace(' ', '_').lower()}_{lighting}.exr", image)
            if peers:
                write_png(args.out / f"side_by_side_tangled_{lighting}.png", tangled_picture(images, peers))
            print(f"[{lighting}] noise level (two warp-hair seeds): block RMSE {noise:.2%}")
            for peer, theirs in peers.items():
                mean_theirs = theirs.mean(axis=(0, 1))
                for ours_name, ours in images.items():
                    ratio = ours.mean(axis=(0, 1)) / mean_theirs
                    rmse = block_rmse(ours, theirs)
                    print(
                        f"[{lighting}] {ours_name} / {peer}: means {fmt(ours.mean(axis=(0, 1)))} / "
                        f"{fmt(mean_theirs)} "
                        f"= {fmt(ratio)}; block RMSE {rmse:.2%} (noise level {noise:.2%})"
                    )
                    rows.append(
                        f"| {lighting} | {ours_name.split()[1]} | {peer} | {fmt(ratio, '.3f')} | {rmse:.1%} | "
                        f"{noise:.1%} |"
                    )
    print("\n| light | warp-hair rule | peer | mean ratio (R, G, B) | block RMSE | noise |")
    print("| --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))
    print(f"images in {args.out}")


# Hair as it grows, on the light-brown look and on a melanin one (`--growing`).
GROWTH = {"color_spread": 0.4, "roughness_spread": 0.25, "tip_absorption": 0.3, "tip_length": 0.5}
GROWING_LOOKS = {
    "albedo": {**HAIR, **GROWTH},
    "melanin": {**{k: v for k, v in HAIR.items() if k != "albedo"}, "eumelanin": 0.5, "pheomelanin": 0.3, **GROWTH},
}


def without_growth(look):
    """The look without its variation (the controls' defaults)."""
    return {k: v for k, v in look.items() if k not in GROWTH}


def growing_renders(bpy, fibers, look, light_direction, resolution, spp, max_depth=100, threads=None, baseline=True):
    """{name: image}: warp-hair's renders of `look` on the Catmull-Rom curve through the fibers' vertices (the
    curve Cycles draws), with seeds 0 ("ours") and 1 ("seed 1"), and of the look without its variation
    ("uniform"); with bpy, Cycles' of the exported look ("Cycles") and, with `baseline`, of the one without
    ("Cycles uniform")."""
    data = scene_data(resolution, light_direction, spp, max_depth=max_depth)
    curve = catmull_rom(fibers)
    images = {}
    for name, hair, seed in (("ours", look, 0), ("seed 1", look, 1), ("uniform", without_growth(look), 0)):
        scene = scene_from_dict({**data, "hair": hair, "render": {**data["render"], "seed": seed}})
        scene.fibers = curve
        images[name] = render(scene, threads=threads)
    if bpy is not None:
        peers = {"Cycles": look, "Cycles uniform": without_growth(look)} if baseline else {"Cycles": look}
        for name, hair in peers.items():
            scene = scene_from_dict({**data, "hair": hair})
            images[name] = render_cycles(bpy, scene, spp, threads=threads, fibers=fibers)
    return images


def growing_statistics(images):
    """The figures `--growing` prints: warp-hair's image means over Cycles' ("ratio", per channel) and their block
    RMSE ("rmse"), the same without the variation ("ratio uniform", "rmse uniform"), the noise level (two
    warp-hair seeds) and how much the variation shows (warp-hair with it against without: "variation")."""
    ours = images["ours"]
    figures = {"noise": block_rmse(images["seed 1"], ours), "variation": block_rmse(images["uniform"], ours)}
    for suffix, mine in (("", "ours"), (" uniform", "uniform")):
        if f"Cycles{suffix}" in images:
            theirs = images[f"Cycles{suffix}"]
            figures[f"ratio{suffix}"] = images[mine].mean(axis=(0, 1)) / theirs.mean(axis=(0, 1))
            figures[f"rmse{suffix}"] = block_rmse(images[mine], theirs)
    return figures


def growing_check(args, fibers, threads):
    """warp-hair against Cycles rendering the exported look, for looks that vary strand by strand and to the tip."""
    bpy = import_bpy()
    rows = []
    for colour in args.looks.split(","):
        for lighting in args.lightings.split(","):
            start = time.perf_counter()
            images = growing_renders(
                bpy,
                fibers,
                GROWING_LOOKS[colour],
                LIGHTINGS[lighting],
                args.resolution,
                args.spp,
                args.max_depth,
                threads,
            )
            for name, image in images.items():
                write_exr(args.out / f"growing_{colour}_{lighting}_{name.replace(' ', '_').lower()}.exr", image)
            f = growing_statistics(images)
            tag = f"[{colour}, {lighting}]"
            print(f"{tag} {time.perf_counter() - start:.1f} s; noise level (two warp-hair seeds): {f['noise']:.2%}")
            print(f"{tag} the variation (warp-hair with it against without): block RMSE {f['variation']:.2%}")
            if bpy is None:
                continue
            means = f"{fmt(images['ours'].mean(axis=(0, 1)))} / {fmt(images['Cycles'].mean(axis=(0, 1)))}"
            rmse = f"block RMSE {f['rmse']:.2%}"
            print(f"{tag} warp-hair / Cycles {bpy.app.version_string}: means {means} = {fmt(f['ratio'])}; {rmse}")
            print(f"{tag} without the variation: means {fmt(f['ratio uniform'])}; block RMSE {f['rmse uniform']:.2%}")
            rows.append(
                f"| {colour} | {lighting} | {fmt(f['ratio'], '.3f')} | {f['rmse']:.1%} | {f['noise']:.1%} | "
                f"{f['variation']:.1%} | {fmt(f['ratio uniform'], '.3f')}, {f['rmse uniform']:.1%} |"
            )
    print(
        "\n| look | light | mean ratio warp-hair / Cycles (R, G, B) | block RMSE | noise | the variation | "
        "without the variation: ratio, block RMSE |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))
    print(f"images in {args.out}")


def tilt_check(args, fibers, threads):
    bpy = import_bpy()
    for alpha in (args.alpha, -args.alpha):
        data = scene_data(args.resolution, LIGHTINGS["front"], args.spp, max_depth=args.max_depth)
        data["hair"] = {**HAIR, "alpha": alpha}
        scene = scene_from_dict(data)
        scene.fibers = fibers
        print(f"warp-hair alpha {alpha:+g} deg: highlight row {highlight_row(render(scene, threads=threads)):.2f}")
        if bpy is not None and alpha == args.alpha:
            cycles = render_cycles(bpy, scene, args.spp, threads=threads)
            print(f"Cycles Offset {np.radians(alpha):+.5f} rad (exported): highlight row {highlight_row(cycles):.2f}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--segments", type=int, default=24, help="segments per strand (default 24)")
    parser.add_argument("--max-depth", type=int, default=100, help="scattering vertices a path may have")
    parser.add_argument("--lightings", default="front,back", help="comma-separated: front, back")
    parser.add_argument(
        "--albedo",
        type=float,
        nargs=3,
        metavar=("R", "G", "B"),
        help=f"the hair's albedo (default {HAIR['albedo']}, light brown)",
    )
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--alpha", type=float, help="check the tilt's sign at this alpha (degrees) against Cycles")
    parser.add_argument(
        "--interpenetrating",
        action="store_true",
        help="issue 23's swatch whose strands pass through each other, under both rules",
    )
    parser.add_argument(
        "--growing", action="store_true", help="hair as it grows (color and roughness spread, tip) against Cycles"
    )
    parser.add_argument("--looks", default="albedo,melanin", help="with --growing, comma-separated: albedo, melanin")
    parser.add_argument("--out", type=Path, default=HERE / "out" / "vs_peers")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.interpenetrating:
        return interpenetrating_check(args, args.threads or default_threads())
    fibers = draped_swatch(args.segments)
    print(
        f"draped swatch: {fibers.num_strands} fibers x {args.segments} segments, {args.resolution}^2 px, "
        f"{args.spp} spp, max depth {args.max_depth}, alpha 0"
    )
    threads = args.threads or default_threads()
    if args.alpha is not None:
        return tilt_check(args, fibers, threads)
    if args.growing:
        return growing_check(args, fibers, threads)
    mi = import_mitsuba()
    bpy = import_bpy()
    with tempfile.TemporaryDirectory() as tmp:
        fibers_file = Path(tmp) / "draped.txt"
        save_fibers(bspline_control_points(fibers), fibers_file)
        for lighting in args.lightings.split(","):
            direction = LIGHTINGS[lighting]
            images = {}
            for shape in ("smooth", "segment", "catmull-rom"):  # the polyline's two tangents, or the curve
                scene = scene_from_dict(
                    scene_data(
                        args.resolution,
                        direction,
                        args.spp,
                        "segment" if shape == "segment" else "smooth",
                        args.max_depth,
                        args.albedo,
                    )
                )
                scene.fibers = catmull_rom(fibers) if shape == "catmull-rom" else fibers
                start = time.perf_counter()
                images[shape] = render(scene, threads=threads)
                print(f"[{lighting}] warp-hair ({shape}): {time.perf_counter() - start:.1f} s")
            scene.fibers = fibers
            noise_scene = dataclasses.replace(
                scene, render=dataclasses.replace(scene.render, seed=1, tangents="smooth")
            )
            noise = block_rmse(render(noise_scene, threads=threads), images["smooth"])
            write_exr(args.out / f"warp_hair_{lighting}.exr", images["smooth"])
            print(f"[{lighting}] noise level (two warp-hair seeds): block RMSE {noise:.2%}")
            print(
                f"[{lighting}] smooth vs segment tangents: block RMSE "
                f"{block_rmse(images['segment'], images['smooth']):.2%}"
            )
            peers = {}
            for sampler in SAMPLERS if mi is not None else ():
                mi_scene = mitsuba_scene(
                    mi, scene, args.spp, shape="bsplinecurve", fibers_file=fibers_file, sampler=sampler
                )
                start = time.perf_counter()
                peers[f"Mitsuba_{sampler} {mi.__version__}"] = time_mitsuba(mi, mi_scene, args.spp, 0, threads, 1)[2]
                print(f"[{lighting}] Mitsuba bsplinecurve, {sampler} sampler: {time.perf_counter() - start:.1f} s")
            if bpy is not None:
                start = time.perf_counter()
                peers[f"Cycles {bpy.app.version_string}"] = render_cycles(bpy, scene, args.spp, threads=threads)
                print(f"[{lighting}] Cycles: {time.perf_counter() - start:.1f} s")
            for peer, theirs in peers.items():
                tag = peer.split()[0].lower()
                write_exr(args.out / f"{tag}_{lighting}.exr", theirs)
                mean_theirs = theirs.mean(axis=(0, 1))
                for shape, ours in images.items():
                    ratio = ours.mean(axis=(0, 1)) / mean_theirs
                    print(
                        f"[{lighting}] warp-hair ({shape}) / {peer}: means {fmt(ours.mean(axis=(0, 1)))} / "
                        f"{fmt(mean_theirs)} = {fmt(ratio)}; block RMSE {block_rmse(ours, theirs):.2%} "
                        f"(noise level {noise:.2%})"
                    )
                exposure = 0.8 / float(np.percentile(theirs, 99.5))  # the peer's brightest pixels near white
                panels = [exposure * images["smooth"], exposure * images["catmull-rom"], exposure * theirs]
                for ours in (images["smooth"], images["catmull-rom"]):
                    # the blocks' difference relative to the peer's mean: mid grey is none, ±10% is ±0.2
                    diff = np.kron((blocks(ours) - blocks(theirs)) / theirs.mean(), np.ones((BLOCK, BLOCK, 1)))
                    pad = ((0, ours.shape[0] - diff.shape[0]), (0, ours.shape[1] - diff.shape[1]), (0, 0))
                    panels.append(0.21 + 2.0 * np.pad(diff, pad, constant_values=0.0))
                image = np.concatenate(panels, axis=1)
                write_png(args.out / f"side_by_side_{tag}_{lighting}.png", np.kron(image, np.ones((2, 2, 1))))
    print(f"images in {args.out}")


if __name__ == "__main__":
    main()
