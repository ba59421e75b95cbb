"""A scene made ready to render: the tubes and their BVH, the camera, the light tables and the card on a device.

    prepared = prepare(scene)                       # build once
    render(prepared.with_hair(other_hair))          # render many times, only the hair changing

A fit renders one scene hundreds of times with only its hair controls changing; preparing it once keeps the
BVH build out of that loop. `render` and `render_jacobian` take a Scene or a PreparedScene alike.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import warp as wp

from .. import validate
from ..devices import check_device
from ..geometry.card import card_data
from ..geometry.tubes import FiberBVH
from ..model.hair_bsdf import HairCoefficients, hair_coefficients, strand_coefficients
from ..model.jacobian import CoefficientDerivatives, strand_derivatives
from ..model.params import HairParams
from ..model.variation import strand_looks, strand_random, strands_vary, tip_varies
from ..scene import DirectionalLight, EnvironmentLight, Scene, check_scene
from .aggregate import Surfaces
from .camera import camera_data
from .envmap import environment_data
from .integrator import DirectionalLightData, SceneData
from .light_sampler import selection_cdf
from .material import HairVariation


class PreparedScene:
    """Everything a render kernel reads, built once per scene and device: the tubes and their BVH, the camera,
    the light tables, the card. `prepare(scene)` makes one; `render` and `render_jacobian` accept it in place of
    the scene. Only the hair coefficients change between a fit's iterations: `with_hair` swaps them and shares
    the rest, so a fit builds its BVH once, and a render of the prepared scene is bit for bit that of the scene.
    Everything lives on `device` (a checked name, `devices.check_device`); the BVH is built on the host and
    uploaded once (geometry/tubes.py says why), and the hair coefficients travel as a launch argument.
    """

    def __init__(self, scene: Scene, device: str = "cpu", bvh: FiberBVH | None = None):
        check_scene(scene)  # a scene built in Python, not loaded, is checked here
        self.scene = scene
        self.device = device = check_device(device)
        # `bvh`: another view's of these very strands (`prepare_views`), else built here.
        smooth = scene.render.tangents == "smooth"
        self.bvh = FiberBVH(scene.fibers, device=device, smooth_tangents=smooth) if bvh is None else bvh
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
        # Which light a shadow ray goes to (light_sampler.py); a scene without lights passes one unread entry.
        cdf = selection_cdf(directional, env) if scene.lights else [1.0]
        self.light_cdf = wp.array(cdf, dtype=float, device=device)
        self._camera = camera_data(scene.camera)
        self._card = card_data(scene.card, scene.camera, self.bvh.bounds)
        # What the variation's controls need of the strands, made once and shared by `with_hair`'s copies: each
        # strand's random value, the segments' arc-length fractions.
        self._strand_data = {}
        self._data = self._gradient_data = None  # made when a pass first asks (`data`, `gradient_data`)
        self.resolution = scene.camera.resolution

    def _variation(self, hair: HairParams, derivatives: bool = False) -> HairVariation:
        """The kernels' HairVariation of a look. With `derivatives` (the gradient pass's, `gradient_data`), each
        strand's derivatives in the variation's controls, there for every look (the gradient at no variation is
        not 0); the segments' arc-length fractions always; each strand's own coefficients and the tip's ramp only
        where the look varies."""
        variation = HairVariation()
        variation.strands = int(strands_vary(hair))
        looks = strand_looks(hair, self._strand_random()) if derivatives or variation.strands else None
        derivs = strand_derivatives(hair, looks) if derivatives else np.zeros(0, CoefficientDerivatives.numpy_dtype())
        variation.derivs = wp.array(derivs, dtype=CoefficientDerivatives, device=self.device)
        coefficients = (
            strand_coefficients(hair, looks) if variation.strands else np.zeros(0, HairCoefficients.numpy_dtype())
        )
        variation.hair = wp.array(coefficients, dtype=HairCoefficients, device=self.device)
        variation.segment_start, variation.segment_span = self._arcs()
        variation.tip = int(tip_varies(hair))
        variation.tip_absorption = float(hair.tip_absorption)
        variation.tip_length = float(hair.tip_length)
        return variation

    def _strand_random(self) -> np.ndarray:
        """Each strand's random value: the fibers' own, else drawn from its index as Cycles draws it."""
        if "random" not in self._strand_data:
            fibers = self.scene.fibers
            given = fibers.strand_random
            self._strand_data["random"] = strand_random(fibers.num_strands) if given is None else given
        return self._strand_data["random"]

    def _arcs(self) -> tuple:
        """The segments' arc-length fractions (start, span) on the device, made once."""
        if "arc" not in self._strand_data:
            start, span = self.scene.fibers.segment_arc_fractions()
            self._strand_data["arc"] = tuple(
                wp.array(x.astype(np.float32), dtype=float, device=self.device) for x in (start, span)
            )
        return self._strand_data["arc"]

    @property
    def data(self) -> SceneData:
        """What the forward pass reads of this look: made when it first runs on it, then kept."""
        if self._data is None:
            self._data = self._scene_data(self.scene.hair)
        return self._data

    def gradient_data(self) -> SceneData:
        """`data` with each strand's derivatives in the variation's controls, which only the gradient pass reads
        (a forward render need not make them: they grow with the strands); made when it first runs on this look,
        then kept. A look a fit renders both ways builds each once."""
        if self._gradient_data is None:
            self._gradient_data = self._scene_data(self.scene.hair, derivatives=True)
        return self._gradient_data

    def _scene_data(self, hair: HairParams, derivatives: bool = False) -> SceneData:
        data = SceneData()
        data.camera = self._camera
        data.surfaces = Surfaces()
        data.surfaces.fibers = self.bvh.geometry
        data.surfaces.card = self._card
        data.surfaces.exits = int(self.scene.render.interpenetration == "exit")
        data.hair = hair_coefficients(hair)
        data.variation = self._variation(hair, derivatives)
        data.lights = self.lights
        data.num_lights = self._num_lights
        data.env = self.env
        data.has_env = self._has_env
        data.light_cdf = self.light_cdf
        data.max_depth = self.scene.render.max_depth
        data.rr_depth = self.scene.render.rr_depth
        return data

    def with_hair(self, hair: HairParams) -> PreparedScene:
        """This prepared scene with other hair controls; the geometry, lights and camera are shared, not rebuilt."""
        if not isinstance(hair, HairParams):
            raise TypeError(
                f"hair must be a HairParams (e.g. scene.hair.replace(albedo=...)), got {type(hair).__name__}"
            )
        other = copy.copy(self)
        other.scene = dataclasses.replace(self.scene, hair=hair)
        other._data = other._gradient_data = None
        return other


def prepare(scene: Scene | PreparedScene, device: str | None = None) -> PreparedScene:
    """The scene made ready to render on `device` ("cpu", the default; "cuda" or "cuda:N"), for rendering it many
    times with only its hair changing (`PreparedScene.with_hair`); a prepared scene is returned as it is (on its
    own device). A device this machine lacks raises ValueError naming the ones it has."""
    if isinstance(scene, PreparedScene):
        if device is not None and check_device(device) != scene.device:
            raise ValueError(f"the scene was prepared on device {scene.device!r}, not {device!r}; prepare it again")
        return scene
    if not isinstance(scene, Scene):
        raise TypeError(f"expected a Scene or a PreparedScene, got {type(scene).__name__}")
    return PreparedScene(scene, device=check_device(device))


def prepare_views(scenes, device: str | None = None) -> list:
    """`prepare` for several views of the same strands: a view holding the very assembly of an earlier one
    (`realisation.realisation_views`) with the same tangents shares its BVH, which is built once."""
    prepared = []
    for scene in scenes:
        shared = next(
            (
                other.bvh
                for other in prepared
                if other.scene.fibers is scene.fibers and other.scene.render.tangents == scene.render.tangents
            ),
            None,
        )
        prepared.append(
            prepare(scene, device) if shared is None else PreparedScene(scene, prepared[0].device, bvh=shared)
        )
    return prepared


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


def sampling(scene: Scene | PreparedScene, spp=None, seed=None) -> tuple:
    """(spp, seed): the given ones, else the scene's [render] table's; spp in [1, 2**31), seed in [0, 2**32)."""
    scene = scene_of(scene)
    spp = scene.render.spp if spp is None else validate.integer("spp", spp, minimum=1)
    seed = scene.render.seed if seed is None else validate.seed("seed", seed)
    return spp, seed
