"""warp-hair: the Chiang et al. hair/fur BSDF in NVIDIA Warp, for rendering and fitting fiber swatches.

    params = warp_hair.HairParams(albedo=[0.6, 0.4, 0.2], beta_m=0.3, beta_n=0.3)
    warp_hair.bsdf.eval(params, wo, wi, h)                  # the BSDF over NumPy arrays
    scene = warp_hair.load_scene("swatch.toml")             # or warp_hair.scene_from_dict({...})
    image = warp_hair.render(scene, spp=64)                 # float32 (H, W, 3) linear radiance
    warp_hair.io.write_exr("swatch.exr", image)

Importing it leaves Warp's settings (its log level among them) as the host program set them; the `warp-hair`
command shows Warp's warnings and errors only.
"""

from . import geometry, io
from .model import bsdf
from .model.params import HairParams
from .renderer.prepare import prepare
from .renderer.render import render
from .scene import load_scene, scene_from_dict

__all__ = ["HairParams", "bsdf", "geometry", "io", "load_scene", "prepare", "render", "scene_from_dict"]
__version__ = "0.1.0"
