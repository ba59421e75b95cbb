"""The small scenes several test files render: a 12×8 command-line scene, a dense swatch and a sparse single layer.

Every one is seen from the front by an orthographic camera on the z axis (`front_camera`).
"""

import tomlkit

from warp_hair.scene import scene_from_dict


def front_camera(width: float, resolution) -> dict:
    """An orthographic camera 3 units up the z axis, looking at the origin with y up, `width` units wide."""
    return {
        "type": "orthographic",
        "origin": [0.0, 0.0, 3.0],
        "target": [0.0, 0.0, 0.0],
        "up": [0.0, 1.0, 0.0],
        "width": width,
        "resolution": list(resolution),
    }


def toml_text(data: dict) -> str:
    """A scene dictionary as a scene file's text."""
    return tomlkit.dumps(data)


# The command-line tests' scene (the `tiny_scene` fixture writes it to a file): 12×8 pixels, 40 fibers, 2 spp.
TINY_SCENE = toml_text(
    {
        "camera": front_camera(0.2, (12, 8)),
        "lights": [{"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]}],
        "fibers": {"generator": "swatch", "count": 40, "layers": 2},
        "hair": {"eumelanin": 1.3},
        "render": {"spp": 2, "max_depth": 8, "seed": 4},
    }
)


def swatch_scene(hair, lights, resolution=(24, 24), render_table=None, card=None):
    """A dense swatch (160 fibers in 4 layers) filling the view, under `lights`."""
    data = {
        "camera": front_camera(0.3, resolution),
        "lights": lights,
        "fibers": {"generator": "swatch", "count": 160, "layers": 4, "length": 0.6, "radius": 0.004, "seed": 3},
        "hair": hair,
        "render": render_table or {"spp": 64, "max_depth": 64, "seed": 1},
    }
    if card is not None:
        data["card"] = card
    return scene_from_dict(data)


# The gradient checks' hair, with every scalar control away from its default.
SPARSE_HAIR = {
    "albedo": [0.7, 0.5, 0.3],
    "beta_m": 0.3,
    "beta_n": 0.35,
    "alpha": 2.0,
    "eta": 1.55,
    "r_roughness_scale": 1.5,
}


def sparse_scene_dict(hair, resolution=(16, 16), spp=128) -> dict:
    """One sparse layer of 24 fibers under a directional light and a constant sky, max_depth 8 without roulette.

    Sparse, so that central differences of `render` with common random numbers are not swamped by the discrete
    choices (lobe, fiber hit) a change of the controls flips (tests/test_render_grad.py says more).
    """
    return {
        "camera": front_camera(0.25, resolution),
        "lights": [
            {"type": "directional", "direction": [0.3, -0.4, -1.0], "irradiance": [3.0, 3.0, 3.0]},
            {"type": "environment", "radiance": [0.3, 0.3, 0.3]},
        ],
        "fibers": {"generator": "swatch", "count": 24, "layers": 1, "length": 0.6, "radius": 0.004, "seed": 3},
        "hair": hair,
        "render": {"spp": spp, "max_depth": 8, "rr_depth": 8, "seed": 1},
    }


def sparse_scene(hair, resolution=(16, 16), spp=128):
    return scene_from_dict(sparse_scene_dict(hair, resolution, spp))


# The shipped targets' two lights: from the viewer's side, and from behind the swatch.
FRONT_BACK = (("front", [0.2, -0.3, -1.0]), ("back", [0.0, -0.15, 1.0]))


# The draped swatches of the fit tests: camera width, pixels a side, the fibers' own keys, max_depth, render seed.
DRAPED_SWATCHES = {
    # 40 fibers, 16×16 pixels: a target small enough for a fit in a test.
    "small": (0.24, 16, {"count": 40, "length": 0.3, "width": 0.22, "drape": 0.15, "segments": 12, "seed": 5}, 8, 2),
    # 120 fibers, 24×24: the fit command's own test (tests/test_fit.py).
    "fit": (0.36, 24, {"count": 120, "length": 0.5, "width": 0.4, "drape": 0.25, "segments": 16, "seed": 4}, 16, 3),
}


def draped_swatch_text(direction, hair: dict, spp: int = 64, size: str = "small") -> str:
    """A two-layer draped swatch (`DRAPED_SWATCHES[size]`) under one directional light, as a scene file's text
    (`write_front_back_target` makes a front- and a back-lit target of it)."""
    view, pixels, fibers, max_depth, seed = DRAPED_SWATCHES[size]
    return toml_text(
        {
            "camera": front_camera(view, (pixels, pixels)),
            "lights": [{"type": "directional", "direction": direction, "irradiance": [3.0, 3.0, 3.0]}],
            "fibers": {"generator": "swatch", "layers": 2, "radius": 0.004, **fibers},
            "hair": dict(hair),
            "render": {"spp": spp, "max_depth": max_depth, "seed": seed},
        }
    )


def small_swatch_text(direction, hair: dict, spp: int = 64) -> str:
    return draped_swatch_text(direction, hair, spp, "small")


def write_front_back_target(directory, scene_text):
    """A target directory of the same scene lit from the front and from behind: `scene_text(direction)` gives
    each scene file; target.toml lists them (the images are left to `make_target`)."""
    for name, direction in FRONT_BACK:
        (directory / f"scene_{name}.toml").write_text(scene_text(direction))
    (directory / "target.toml").write_text(
        "".join(f'[[images]]\nscene = "scene_{name}.toml"\nimage = "{name}.exr"\n\n' for name, _ in FRONT_BACK)
    )
    return directory
