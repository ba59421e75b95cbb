"""Benchmark: does a lat-long environment map mean the same in Cycles and in warp-hair? A lit swatch, both renderers.

    python benchmarks/envmap_vs_cycles.py [--spp 256] [--resolution 64] [--threads N] [--out DIR]

The draped swatch of benchmarks/vs_peers.py (4 layers of 38 fibers that do not touch, drawn as the Catmull-Rom
curve through their vertices, as Cycles draws them), turned 30° about the view axis so that it is not its own
mirror image, lit by nothing but benchmarks/synthetic_sky.py's map: a sun
disc off every axis (up, to the viewer's left, in front) over coloured gradients, so that a map read with another
orientation lights the swatch differently. Cycles reads the same EXR through an Environment Texture
(benchmarks/cycles_peer.py, `_environment_map`, translates warp-hair's convention, +y up and u = 0 looking down
−z, into Cycles' from its source). It prints, for warp-hair against Cycles, the ratio of the channel means and
the RMS relative difference of 8×8-block means, beside the same statistic between two warp-hair seeds (the noise
level); then the same for warp-hair reading the map wrongly (u mirrored, v upside down, turned a quarter about
+y, +z up), which shows how far a convention error would move the figures. Writes the EXRs, the map and
`side_by_side_envmap.png` (warp-hair | Cycles | the map) to --out. Needs the `blender` extra (bpy 4.5).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from cycles_peer import import_bpy, render_cycles
from synthetic_sky import synthetic_sky
from vs_peers import block_rmse, draped_swatch, fmt, scene_data

from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.geometry.curves import catmull_rom
from warp_hair.io import write_exr, write_png
from warp_hair.parallel import default_threads
from warp_hair.renderer.render import render
from warp_hair.scene import scene_from_dict

HERE = Path(__file__).resolve().parent
SWATCH_TURN = 30.0  # degrees about the view axis
# An odd number of rows puts the horizon in the middle of a row: the orthographic camera's rays that miss the
# swatch look exactly along the horizon (v = 1/2), which with an even number falls on the edge between a sky
# row and a ground row, where either renderer may round either way.
MAP_HEIGHT = 129

# Readings of the map that a convention error would give: (name, the image warp-hair would then see).
WRONG_READINGS = {
    "u mirrored": lambda image: image[:, ::-1],
    "v upside down": lambda image: image[::-1],
    "turned 90° about +y": lambda image: np.roll(image, image.shape[1] // 4, axis=1),
    # A +z-up map read as +y-up: the sun and the ground move to other sides.
    "+z up read as +y up": lambda image: _z_up(image),
}


def _z_up(image):
    """The map a renderer with +z up would show in warp-hair's convention: each pixel takes the radiance of the
    direction (x, y, z) → (x, −z, y) turned a quarter about +x."""
    from warp_hair.renderer.envmap import pixel_directions

    h, w = image.shape[:2]
    d = pixel_directions(w, h)
    x, y, z = d[..., 0], d[..., 2], -d[..., 1]
    u = (np.arctan2(x, -z) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(y, -1, 1)) / np.pi
    return image[np.minimum((v * h).astype(int), h - 1), np.minimum((u * w).astype(int), w - 1)]


def turned(fibers, degrees):
    """The fibers turned about the view axis (z): a swatch along y is its own mirror image in x, which would hide
    a mirrored u."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=np.float32)
    return FiberAssembly(fibers.points @ rotation.T, fibers.radii, fibers.strand_offsets)


def envmap_scene(resolution, spp, map_file, seed=0):
    data = scene_data(resolution, [0.0, 0.0, -1.0], spp)
    data["lights"] = [{"type": "environment", "file": str(map_file)}]
    data["render"]["seed"] = seed
    return scene_from_dict(data)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--out", type=Path, default=HERE / "out" / "envmap")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    threads = args.threads or default_threads()
    sky = synthetic_sky(height=MAP_HEIGHT)
    map_file = args.out / "synthetic_sky.exr"
    write_exr(map_file, sky)
    fibers = turned(draped_swatch(24), SWATCH_TURN)
    curve = catmull_rom(fibers)
    print(
        f"draped swatch, {fibers.num_strands} fibers, {args.resolution}^2 px, {args.spp} spp, lit by a "
        f"{sky.shape[1]}x{sky.shape[0]} lat-long map only"
    )

    def ours(image_file, seed=0):
        scene = envmap_scene(args.resolution, args.spp, image_file, seed)
        scene.fibers = curve
        start = time.perf_counter()
        image = render(scene, threads=threads)
        return image, time.perf_counter() - start

    image, seconds = ours(map_file)
    print(f"warp-hair: {seconds:.1f} s")
    noise = block_rmse(ours(map_file, seed=1)[0], image)
    write_exr(args.out / "warp_hair_envmap.exr", image)
    bpy = import_bpy()
    if bpy is None:
        return
    scene = envmap_scene(args.resolution, args.spp, map_file)
    scene.fibers = fibers  # Cycles draws its own curves through the vertices
    start = time.perf_counter()
    cycles = render_cycles(bpy, scene, args.spp, threads=threads)
    print(f"Cycles {bpy.app.version_string}: {time.perf_counter() - start:.1f} s")
    write_exr(args.out / "cycles_envmap.exr", cycles)
    rows = [("warp-hair", image)]
    for name, wrong in WRONG_READINGS.items():
        wrong_file = args.out / f"sky_{name.split()[0].replace('+', '')}_{len(rows)}.exr"
        write_exr(wrong_file, wrong(sky))
        rows.append((f"warp-hair, map {name}", ours(wrong_file)[0]))
    print(f"noise level (two warp-hair seeds): block RMSE {noise:.2%}")
    print("\n| warp-hair reading the map | / Cycles, channel means (R, G, B) | block RMSE (noise) |")
    print("| --- | --- | --- |")
    for name, picture in rows:
        ratio = picture.mean(axis=(0, 1)) / cycles.mean(axis=(0, 1))
        reading = "as its convention says" if name == "warp-hair" else name.removeprefix("warp-hair, map ")
        print(f"| {reading} | {fmt(ratio, '.4f')} | {block_rmse(picture, cycles):.2%} ({noise:.2%}) |")
    print(f"means: warp-hair {fmt(image.mean(axis=(0, 1)))}, Cycles {fmt(cycles.mean(axis=(0, 1)))}")
    exposure = 0.8 / float(np.percentile(cycles, 99.5))
    thumbnail = np.clip(sky, 0, 4.0 * np.percentile(sky, 90))[:: max(1, sky.shape[0] // args.resolution)]
    thumbnail = thumbnail[:, :: max(1, thumbnail.shape[1] // (2 * args.resolution))][: args.resolution]
    panel = np.zeros((args.resolution, thumbnail.shape[1], 3), dtype=np.float32)
    panel[: thumbnail.shape[0]] = thumbnail * (0.8 / float(np.percentile(thumbnail, 99)))
    side = np.concatenate([exposure * image, exposure * cycles, panel], axis=1)
    write_png(args.out / "side_by_side_envmap.png", np.kron(side, np.ones((2, 2, 1))))
    print(f"images in {args.out}")


if __name__ == "__main__":
    main()
