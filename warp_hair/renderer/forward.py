"""Render a scene: the Python front of the path tracer.

The image is split into tiles of rows, each launched from a thread pool (a Warp CPU launch runs on one
core); every pixel owns its random stream, so the image depends on the seed only, not on the threads.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import warp as wp

from .camera import camera_data
from ..geometry.card import card_data
from .envmap import environment_data
from ..model.hair_bsdf import hair_coefficients
from .integrator import DirectionalLightData, SceneData, render_kernel
from ..geometry.tubes import FiberBVH
from ..model.params import HairParams
from ..parallel import launch_ranges
from .. import validate
from ..scene import DirectionalLight, EnvironmentLight, Scene, check_scene


# Pixels per range handed to a thread: fiber pixels cost far more than background ones, and small ranges
# balance the threads at a negligible cost per launch (a fit's 48×48 targets are 9 ranges, not one core's work).
TILE_PIXELS = 256
# Above this spp a range holds proportionally fewer pixels, so that one range stays a fraction of a second and
# Ctrl-C, which lets the running ranges finish, stops a render at any spp within about a second.
TILE_SPP = 64


def tile_pixels(spp: int) -> int:
    return max(1, TILE_PIXELS * TILE_SPP // max(spp, TILE_SPP))


class PreparedScene:
    """Everything a render kernel reads, built once per scene and device: the tubes and their BVH, the camera,
    the light tables, the card. `prepare(scene)` makes one; `render` and `render_jacobian` accept it in place of
    the scene. Only the hair coefficients change between a fit's iterations: `with_hair` swaps them and shares
    the rest, so a fit builds its BVH once, and a render of the prepared scene is bit for bit that of the scene.
    """

    def __init__(self, scene: Scene, device: str = "cpu"):
        check_scene(scene)  # a scene built in Python, not loaded, is checked here
        self.scene = scene
        self.device = device
        self.bvh = FiberBVH(scene.fibers, device=device, smooth_tangents=scene.render.tangents == "smooth")
        directional = [light for light in scene.lights if isinstance(light, DirectionalLight)]
        environments = [light for light in scene.lights if isinstance(light, EnvironmentLight)]
        if len(environments) > 1:
            raise ValueError("a scene can have at most one environment light")
        self.lights = wp.array(
            [_directional_data(light) for light in directional] or [_directional_data(None)],
            dtype=DirectionalLightData,
            device=device,
        )
        env = environments[0] if environments else None
        self.env, self._env_keepalive = environment_data(
            radiance=None if env is None or env.image is not None else env.radiance,
            image=None if env is None else env.image,
            device=device,
        )
        self._num_lights = len(directional)
        self._has_env = int(env is not None)
        self._camera = camera_data(scene.camera)
        self._card = card_data(scene.card, scene.camera, self.bvh.bounds)
        self.data = self._scene_data(hair_coefficients(scene.hair))
        self.resolution = scene.camera.resolution

    def _scene_data(self, hair) -> SceneData:
        data = SceneData()
        data.camera = self._camera
        data.fibers = self.bvh.geometry
        data.hair = hair
        data.lights = self.lights
        data.num_lights = self._num_lights
        data.env = self.env
        data.has_env = self._has_env
        data.card = self._card
        data.max_depth = self.scene.render.max_depth
        data.rr_depth = self.scene.render.rr_depth
        return data

    def with_hair(self, hair: HairParams) -> "PreparedScene":
        """This prepared scene with other hair controls; the geometry, lights and camera are shared, not rebuilt."""
        if not isinstance(hair, HairParams):
            raise TypeError(f"hair must be a HairParams (e.g. scene.hair.replace(albedo=...)), got {type(hair).__name__}")
        other = copy.copy(self)
        other.scene = dataclasses.replace(self.scene, hair=hair)
        other.data = self._scene_data(hair_coefficients(hair))
        return other


def _same_device(a: str, b: str) -> bool:
    try:
        return wp.get_device(a) == wp.get_device(b)
    except ValueError:  # not a device on this machine
        return False


def prepare(scene: Scene | PreparedScene, device: str | None = None) -> PreparedScene:
    """The scene made ready to render on `device` (default "cpu"), for rendering it many times with only its
    hair changing (`PreparedScene.with_hair`); a prepared scene is returned as it is (on its own device)."""
    if isinstance(scene, PreparedScene):
        if device is not None and not _same_device(device, scene.device):
            raise ValueError(f"the scene was prepared on device {scene.device!r}, not {device!r}; prepare it again")
        return scene
    if not isinstance(scene, Scene):
        raise TypeError(f"expected a Scene or a PreparedScene, got {type(scene).__name__}")
    return PreparedScene(scene, device="cpu" if device is None else device)


def _directional_data(light: DirectionalLight | None) -> DirectionalLightData:
    data = DirectionalLightData()
    if light is None:
        data.to_light = wp.vec3(0.0, 0.0, 1.0)
        data.irradiance = wp.vec3(0.0, 0.0, 0.0)
        return data
    travel = np.asarray(light.direction, dtype=np.float64)
    data.to_light = wp.vec3(*(-travel / np.linalg.norm(travel)))
    data.irradiance = wp.vec3(*light.irradiance)
    return data


def scene_of(scene: Scene | PreparedScene) -> Scene:
    """The Scene itself, of a Scene or a PreparedScene."""
    return scene.scene if isinstance(scene, PreparedScene) else scene


def render_metadata(scene: Scene, spp: int, seed: int) -> dict:
    """What an image's EXR header records of how it was made."""
    from .. import __version__

    return {
        "warp_hair": {
            "version": __version__,
            "scene": scene.source,
            "hair": scene.hair.to_table(),
            "sigma_a": [float(c) for c in scene.hair.sigma_a],
            "spp": spp,
            "seed": seed,
        }
    }


def sampling(scene: Scene | PreparedScene, spp=None, seed=None) -> tuple:
    """(spp, seed): the given ones, else the scene's [render] table's; spp in [1, 2**31), seed in [0, 2**32)."""
    scene = scene_of(scene)
    spp = scene.render.spp if spp is None else validate.integer("spp", spp, minimum=1)
    seed = scene.render.seed if seed is None else validate.seed("seed", seed)
    return spp, seed


def render(
    scene: Scene | PreparedScene,
    spp: int | None = None,
    seed: int | None = None,
    threads: int | None = None,
    device: str | None = None,
    progress=None,
    return_stderr: bool = False,
):
    """Linear radiance, float32 (H, W, 3), row 0 at the top.

    `scene` is a Scene, or a PreparedScene (`prepare(scene)`) to skip building the BVH again; `device` defaults
    to the prepared scene's, else "cpu". spp and seed default to the scene's [render] table.
    `progress(done, total)` is called as tiles finish.
    With `return_stderr`, returns (image, stderr): the standard error of each pixel's mean, estimated from
    the spread of its own samples.
    """
    spp, seed = sampling(scene, spp, seed)
    prepared = prepare(scene, device)
    device = prepared.device
    width, height = prepared.resolution
    image = wp.zeros(width * height, dtype=wp.vec3, device=device)
    stderr = wp.zeros(width * height, dtype=wp.vec3, device=device)
    launch_ranges(
        render_kernel,
        width * height,
        [prepared.data, spp, seed, image, stderr],
        threads=threads,
        device=device,
        chunk=tile_pixels(spp),
        progress=progress,
    )
    image = image.numpy().reshape(height, width, 3)
    if return_stderr:
        return image, stderr.numpy().reshape(height, width, 3)
    return image
