"""Five looks side by side under a sky and a sun: blonde, brown and black swatches draped over a rod, hair as it
grows, and a fur patch.

    python examples/gallery.py                       # writes docs/gallery.png (about 7 minutes on 2 cores at 384 spp)
    python examples/gallery.py --spp 16 -o quick.png  # a quick look

The sky is a lat-long image made here (blue zenith, pale horizon, dim ground) and passed to the scene as an
EXR file, as a scene file's `[[lights]] type = "environment", file = "sky.exr"` would; the sun is a
directional light. Each swatch is laid over a cylinder (`drape`), so the angle between fibers, camera and sun
sweeps along the strands and one picture shows both highlights: the primary (R, white: light reflected off
the cuticle) and the secondary (TRT, tinted by the fiber's colour: light that entered the fiber and reflected
off its back), which the cuticle tilt α sets apart. The tilt turns R toward the roots and TRT toward the tips,
so on a swatch that curves away from the viewer R shows nearer the tips (the top of each panel; the roots are
at the bottom) and TRT nearer the roots. Black hair absorbs the secondary; on blonde it is a golden band.
The fourth swatch is hair as it grows (docs/MODEL.md, "Strand-to-strand and root-to-tip variation"): each strand's
pigment and roughness its own (`color_spread`, `roughness_spread`, as Cycles' Random Color and Random Roughness),
and the ends lighter than the roots (`tip_absorption`: 6% of the root's absorption at the tip, as sun-bleached
ends) over the last 70% of each strand (`tip_length`), the strands' upper part in the panel.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

import warp_hair as wh

ROOT = Path(__file__).resolve().parent.parent

# The swatches: 240 slightly wavy fibers in 4 layers, draped over a rod of radius 0.5 and seen from the front.
SWATCH = {
    "generator": "wavy",
    "count": 240,
    "layers": 4,
    "length": 1.3,
    "radius": 0.004,
    "width": 0.42,
    "amplitude": 0.004,
    "wavelength": 0.33,
    "phase_jitter": 0.1,
    "drape": 0.5,
    "seed": 3,
}
SWATCH_CAMERA = {
    "type": "perspective",
    "origin": [0.0, 0.05, 2.6],
    "target": [0.0, 0.0, -0.15],
    "up": [0.0, 1.0, 0.0],
    "fov": 16.0,
}
# The sun high behind the viewer's right shoulder (the way its light travels; +y is up).
SWATCH_SUN = {"direction": [-0.25, -0.45, -0.86], "irradiance": [3.2, 3.0, 2.7]}
# The fur: a patch seen from low at its side, the tips against the backdrop and its front edge below the frame.
FUR = {
    "generator": "fur",
    "count": 6000,
    "patch": [0.5, 0.6],
    "length": 0.22,
    "root_radius": 0.003,
    "tip_radius": 0.0005,
    "lean": 30.0,
    "bend": 25.0,
    "segments": 8,
    "seed": 4,
}
FUR_CAMERA = {
    "type": "perspective",
    "origin": [0.0, -1.6, 0.45],
    "target": [0.0, 0.0, 0.13],
    "up": [0.0, 0.0, 1.0],
    "fov": 10.0,
}
FUR_SUN = {"direction": [-0.3, 0.55, -0.78], "irradiance": [3.2, 3.0, 2.7]}  # +z is up here
# A dark backdrop behind each panel, so the highlights stand out; the sky still lights the fibers.
CARD = {"albedo": [0.03, 0.03, 0.03], "distance": 0.05}
# Human hair's cuticle tilt is 2–4°; 5° with a low β_m parts the two highlights clearly at this size.
TILT = {"beta_m": 0.12, "beta_n": 0.3, "alpha": 5.0}
PANELS = [  # (name, [fibers], [hair], camera, sun)
    ("blonde", SWATCH, {"eumelanin": 0.25, "pheomelanin": 0.25, **TILT}, SWATCH_CAMERA, SWATCH_SUN),
    ("brown", SWATCH, {"eumelanin": 1.2, "pheomelanin": 0.35, **TILT}, SWATCH_CAMERA, SWATCH_SUN),
    ("black", SWATCH, {"eumelanin": 8.0, **TILT}, SWATCH_CAMERA, SWATCH_SUN),
    (
        "grown",
        SWATCH,
        {
            "eumelanin": 1.0,
            "pheomelanin": 0.45,
            "color_spread": 0.5,
            "roughness_spread": 0.3,
            "tip_absorption": 0.06,
            "tip_length": 0.7,
            **TILT,
        },
        SWATCH_CAMERA,
        SWATCH_SUN,
    ),
    (
        "fur",
        FUR,
        {"albedo": [0.35, 0.17, 0.07], "beta_m": 0.3, "beta_n": 0.45, "alpha": 3.0, "r_roughness_scale": 2.0},
        FUR_CAMERA,
        FUR_SUN,
    ),
]


def sky(height=64, width=128):
    """A lat-long sky (Mitsuba's convention, +y up, row 0 the zenith): blue above, pale at the horizon, dim ground."""
    theta = (np.arange(height) + 0.5) / height * np.pi  # polar angle from +y
    elevation = np.pi / 2 - theta
    up = np.clip(np.sin(elevation), 0.0, 1.0)[:, None]
    zenith, horizon, ground = np.array([0.25, 0.45, 0.95]), np.array([1.0, 0.95, 0.85]), np.array([0.18, 0.15, 0.12])
    above = horizon + (zenith - horizon) * up**0.5
    rows = np.where((elevation > 0)[:, None], above, ground)
    return np.broadcast_to(rows[:, None, :], (height, width, 3)).astype(np.float32) * np.float32(0.5)


def scene(fibers, hair, camera, sun, sky_file, resolution, spp):
    """The scene file's tables as a dict: what `warp-hair render` would read from TOML."""
    return wh.scene_from_dict(
        {
            "camera": {**camera, "resolution": list(resolution)},
            "lights": [{"type": "directional", **sun}, {"type": "environment", "file": str(sky_file)}],
            "fibers": fibers,
            "hair": hair,
            "card": CARD,
            "render": {"spp": spp, "max_depth": 32, "seed": 0},
        }
    )


def tone_map(image, exposure):
    """Reinhard on each channel after the exposure, so the primary highlight rolls off instead of clipping."""
    x = image * exposure
    return x / (1.0 + x / 4.0) / (1.0 / (1.0 + 1.0 / 4.0))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--spp", type=int, default=384)
    parser.add_argument("--width", type=int, default=200, help="each panel's width in pixels (height 1.5×)")
    parser.add_argument("--exposure", type=float, default=1.0)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "gallery.png")
    args = parser.parse_args()
    resolution = (args.width, round(args.width * 1.5))
    with tempfile.TemporaryDirectory() as folder:
        sky_file = Path(folder) / "sky.exr"
        wh.io.write_exr(sky_file, sky())
        scenes = [scene(*panel[1:], sky_file, resolution, args.spp) for panel in PANELS]
        pixels = resolution[0] * resolution[1]
        images = []
        with tqdm(total=pixels * len(PANELS), unit="px", unit_scale=True, desc="gallery") as bar:
            for (name, *_), s in zip(PANELS, scenes):
                bar.set_postfix_str(name)
                base = bar.n

                def progress(done, total, base=base):
                    bar.update(base + done * pixels // total - bar.n)

                images.append(wh.render(s, threads=args.threads, progress=progress))
    write_gallery(args.output, images, args.exposure)
    print(f"wrote {args.output}")


def write_gallery(path, images, exposure, gap=6):
    """The panels in a row on a dark strip, tone-mapped, as an sRGB PNG."""
    height, width = images[0].shape[:2]
    strip = np.full((height + 2 * gap, len(images) * (width + gap) + gap, 3), 0.004, dtype=np.float32)
    for k, image in enumerate(images):
        left = gap + k * (width + gap)
        strip[gap : gap + height, left : left + width] = tone_map(image, exposure)
    path.parent.mkdir(parents=True, exist_ok=True)
    wh.io.write_png(path, strip)


if __name__ == "__main__":
    main()
