"""warp-hair: the Chiang et al. hair/fur BSDF in NVIDIA Warp, for rendering and fitting fiber swatches.

    params = warp_hair.HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.3, beta_n=0.3)
    warp_hair.bsdf.eval(params, wo, wi, h)                  # the BSDF over NumPy arrays
    scene = warp_hair.load_scene("swatch.toml")             # or warp_hair.scene_from_dict({...})
    image = warp_hair.render(scene, spp=64)                 # float32 (H, W, 3) linear radiance
    warp_hair.io.write_exr("swatch.exr", image)
"""

import warp as wp

# Warp logs every module load at INFO; users want warnings and errors only.
wp.config.log_level = wp.LOG_WARNING

from . import geometry, io  # noqa: E402
from .model import bsdf  # noqa: E402
from .model.params import HairParams  # noqa: E402
from .renderer.forward import prepare, render  # noqa: E402
from .scene import load_scene, scene_from_dict  # noqa: E402

__all__ = ["HairParams", "bsdf", "geometry", "io", "load_scene", "prepare", "render", "scene_from_dict"]
__version__ = "0.1.0"
