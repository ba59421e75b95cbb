"""Scenes: camera, lights, fibers, hair controls and render settings, loaded from a TOML file.

A scene file has the tables `[camera]`, `[[lights]]` (one or more), `[fibers]`, `[hair]`, and optionally
`[render]` and `[card]`; see benchmarks/standard_swatch.toml. Validation is strict: an unknown key, a value of
the wrong type or outside its range raises a ValueError naming the file, the table and the key, for example
``scene.toml: [camera] resolution must be two positive integers, got [256]``.

The dataclasses check their own values (so a scene built in Python is checked too); the loader adds the
file and table to their messages and checks what only a file can get wrong (unknown keys, missing tables).
"""

from __future__ import annotations

import copy
import inspect
import math
import numbers
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

import numpy as np

from . import geometry as fiber_module
from . import validate
from .controls import CONTROL_NAMES
from .geometry.assembly import FiberAssembly
from .geometry.curves import DEFAULT_TOLERANCE, catmull_rom
from .geometry.formats import load_fibers
from .geometry.interpenetration import warn_interpenetration
from .geometry.usd import SUFFIXES as USD_SUFFIXES
from .io import read_exr, read_toml
from .model.params import ALBEDO_INVERSION_KEY, HairParams
from .model.variation import strand_random

CAMERA_TYPES = ("orthographic", "perspective")
TABLES = ("camera", "lights", "fibers", "hair", "render", "card")
GENERATORS = {name: getattr(fiber_module, name) for name in ("swatch", "wavy", "curly", "fur")}
# The [fibers] keys a USD file takes besides `file` (warp_hair.geometry.usd documents them).
USD_FIBER_OPTIONS = ("prim", "radius", "tolerance", "segments")
# What a polyline source (a .txt or .hair file, a generator) may be drawn as: its vertices joined by straight
# segments, or the Catmull-Rom curve through them (warp_hair.geometry.curves), within `tolerance` radii.
CURVE_KINDS = ("polyline", "catmull-rom")
CURVE_OPTIONS = ("curve", "tolerance")
# Each strand's random value for the variation's controls (model/variation.py): lookup3 of (index, random_seed);
# 0, the default, is what Cycles draws for a Blender hair curve.
RANDOM_SEED = "random_seed"
# Generator arguments that must be integers; `patch` takes one number or two; every other argument one number.
INTEGER_GENERATOR_ARGS = frozenset({"count", "layers", "segments", "seed", "clumps", "strays"})
PAIR_GENERATOR_ARGS = frozenset({"patch"})
# Below this sine of the angle between up and the view direction, the camera frame is undefined.
PARALLEL_TOLERANCE = 1e-6


# ---------------------------------------------------------------------------------------------------------------
# Value checks shared by the dataclasses (the limits themselves are warp_hair.validate's). Each returns the
# cleaned value or raises a ValueError naming the key.


def _number(name, value):
    return validate.real(name, value)


def _integer(name, value, minimum=None):
    return validate.integer(name, value, minimum=minimum)


def _vec3(name, value):
    return validate.triple(name, value)


def _colour(name, value, upper=math.inf):
    rgb = _vec3(name, value)
    if not all(0.0 <= c <= upper for c in rgb):
        bound = "≥ 0" if upper == math.inf else f"in [0, {upper:g}]"
        raise ValueError(f"{name} must be three numbers {bound}, got {value!r}")
    return rgb


def _unit(name, value):
    return tuple(float(c) for c in validate.unit(name, value))


def _set(instance, name, value):
    # The dataclasses are frozen; __post_init__ stores the cleaned values the way dataclasses themselves do.
    object.__setattr__(instance, name, value)


# ---------------------------------------------------------------------------------------------------------------
# Scene parts


@dataclass(frozen=True, kw_only=True)
class Camera:
    """An orthographic or perspective camera looking from `origin` at `target`.

    Seen through the camera, `up` points to the top of the image and forward × up to the right (pbrt's and
    Mitsuba's orientation). Orthographic: `width` is the horizontal extent of the view in scene units, the
    vertical extent width·H/W. Perspective: `fov` is the horizontal field of view in degrees, in (0, 180).
    `resolution` is (width, height) in pixels.
    """

    type: str
    origin: tuple
    target: tuple
    up: tuple
    resolution: tuple
    width: float | None = None
    fov: float | None = None

    def __post_init__(self):
        if self.type not in CAMERA_TYPES:
            raise ValueError(f"type must be one of {list(CAMERA_TYPES)}, got {self.type!r}")
        for name in ("origin", "target"):
            _set(self, name, validate.position(name, getattr(self, name)))
        _set(self, "up", _vec3("up", self.up))
        _set(self, "resolution", _resolution(self.resolution))
        if self.type == "orthographic":
            _set(self, "width", self._lens("width", "fov", lambda w: w > 0, "> 0"))
            validate.length("width", self.width, positive=True)
        else:
            _set(self, "fov", self._lens("fov", "width", lambda f: 0 < f < 180, "in (0, 180) degrees"))
        self._check_frame()

    def _lens(self, key, other, valid, condition):
        """The camera type's own lens parameter (`key`), checked; the other type's must be absent."""
        if getattr(self, other) is not None:
            raise ValueError(f"{other} does not apply to {self.type} cameras (they take {key})")
        value = getattr(self, key)
        if value is None:
            raise ValueError(f"{key} is required for {self.type} cameras")
        value = _number(key, value)
        if not valid(value):
            raise ValueError(f"{key} must be {condition}, got {value!r}")
        return value

    def _check_frame(self):
        if self.origin == self.target:
            raise ValueError(f"target must differ from origin, both are {list(self.origin)}")
        # Checked on the unit vectors the kernels get: a tiny or huge `up` has a norm that under- or overflows.
        forward, up = self._directions()
        sine = np.linalg.norm(np.cross(forward, up))
        if not sine >= PARALLEL_TOLERANCE:
            raise ValueError(
                f"up {list(self.up)} must not be parallel to the view direction "
                f"{np.subtract(self.target, self.origin).tolist()}"
            )

    def _directions(self):
        """Unit forward and unit up, float64."""
        view = np.subtract(self.target, self.origin)
        if not np.isfinite(view).all() or not view.any():
            raise ValueError(f"target - origin must be a finite nonzero vector, got {view.tolist()}")
        return validate.unit("target - origin", view), validate.unit("up", self.up)

    def frame(self):
        """(forward, right, up): the camera's orthonormal frame, float64 (3,) each, as the docstring orients it."""
        forward, up = self._directions()
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        return forward, right, np.cross(right, forward)


def _resolution(value):
    if (
        not isinstance(value, (list, tuple, np.ndarray))
        or len(value) != 2
        or not all(isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)) and v > 0 for v in value)
    ):
        raise ValueError(f"resolution must be two positive integers, got {value!r}")
    width, height = int(value[0]), int(value[1])
    if width * height > validate.INT32_MAX:
        raise ValueError(
            f"resolution {width}x{height} has more than {validate.INT32_MAX} pixels, the most a render indexes"
        )
    return (width, height)


@dataclass(frozen=True, kw_only=True)
class DirectionalLight:
    """A distant light. `direction` is the way the light TRAVELS (stored as a unit vector); `irradiance` the RGB
    irradiance it gives a surface facing it."""

    direction: tuple
    irradiance: tuple

    def __post_init__(self):
        _set(self, "direction", _unit("direction", self.direction))
        _set(self, "irradiance", validate.radiance("irradiance", self.irradiance))


@dataclass(frozen=True, kw_only=True)
class EnvironmentLight:
    """Light from every direction: a constant RGB `radiance`, or a lat-long EXR `file`.

    With a file, `image` is its pixels, float32 (H, W, 3), times `scale` (loaded here; a relative path is
    relative to the current directory, the scene loader makes it relative to the scene file). `image` does not
    take part in comparisons: `file` and `scale` determine it.
    """

    radiance: tuple | None = None
    file: Path | None = None
    scale: float = 1.0
    image: np.ndarray | None = field(default=None, init=False, compare=False, repr=False)

    def __post_init__(self):
        if (self.radiance is None) == (self.file is None):
            raise ValueError("needs exactly one of radiance (a constant) and file (a lat-long EXR image)")
        scale = _number("scale", self.scale)
        if scale < 0:
            raise ValueError(f"scale must be ≥ 0, got {scale!r}")
        _set(self, "scale", scale)
        if self.radiance is not None:
            if scale != 1.0:
                raise ValueError("scale applies to an image file only; scale the radiance itself")
            _set(self, "radiance", validate.radiance("radiance", self.radiance))
        else:
            _set(self, "file", Path(self.file))
            _set(self, "image", _environment_image(self.file, scale))


def _environment_image(path, scale):
    try:
        image, _ = read_exr(path)
    except (OSError, ValueError) as error:
        raise ValueError(f"file: {error}") from None
    if not np.isfinite(image).all() or (image < 0).any():
        raise ValueError(f"file: {path} holds negative or non-finite radiance")
    with np.errstate(over="ignore"):
        image = image * np.float32(scale)
    validate.radiance_image(f"file: {path} times scale {scale:g}", image)
    return image


@dataclass(frozen=True, kw_only=True)
class Card:
    """A diffuse backing card: an infinite plane perpendicular to the camera's view direction, `distance`
    behind the fiber point farthest along it, two-sided Lambertian with RGB `albedo`."""

    albedo: tuple
    distance: float = 0.05

    def __post_init__(self):
        _set(self, "albedo", _colour("albedo", self.albedo, upper=1.0))
        distance = validate.length("distance", self.distance, positive=True)
        _set(self, "distance", distance)


TANGENT_MODES = ("smooth", "segment")
# What a ray sees of a tube it starts inside (warp_hair.geometry.intersect; docs/scenes.md, "Interpenetrating
# strands"): "enter" only the hits where a ray enters a tube (as Mitsuba 3 renders), "exit" also where it leaves
# another strand's tube, skipping the whole strand it leaves (as Cycles 4.x renders on the CPU).
INTERPENETRATION_RULES = ("enter", "exit")


@dataclass(frozen=True, kw_only=True)
class RenderSettings:
    """Samples per pixel, the longest path (bounces), the seed, the bounce after which Russian roulette
    may end paths, and the fibers' shading tangents: "smooth" (turning continuously along each strand, as the
    curve through its vertices does) or "segment" (each segment's own axis, the polyline's frame with its steps
    at the joints; `warp_hair.geometry.intersect` explains both), and what a ray sees of a tube it starts inside,
    which matters only where strands interpenetrate: "enter" (only entering hits) or "exit" (also exits, as
    Cycles 4.x on the CPU; see INTERPENETRATION_RULES)."""

    spp: int = 64
    max_depth: int = 64
    seed: int = 0
    rr_depth: int = 8
    tangents: str = "smooth"
    interpenetration: str = "enter"

    def __post_init__(self):
        _set(self, "spp", _integer("spp", self.spp, minimum=1))
        _set(self, "max_depth", _integer("max_depth", self.max_depth, minimum=1))
        _set(self, "rr_depth", _integer("rr_depth", self.rr_depth, minimum=0))
        _set(self, "seed", validate.seed("seed", self.seed))
        if self.tangents not in TANGENT_MODES:
            raise ValueError(f"tangents must be one of {list(TANGENT_MODES)}, got {self.tangents!r}")
        if self.interpenetration not in INTERPENETRATION_RULES:
            raise ValueError(
                f"interpenetration must be one of {list(INTERPENETRATION_RULES)}, got {self.interpenetration!r}"
            )


@dataclass
class Scene:
    """Everything a render needs. `source` is the scene as a TOML-like dict (file paths absolute), for
    recording how an image was made; `path` the scene file, if it came from one."""

    camera: Camera
    lights: list
    fibers: FiberAssembly
    hair: HairParams
    render: RenderSettings = field(default_factory=RenderSettings)
    card: Card | None = None
    source: dict = field(default_factory=dict)
    path: Path | None = None


# ---------------------------------------------------------------------------------------------------------------
# Loading


def load_scene(path) -> Scene:
    """Load and validate a TOML scene file; relative file paths in it are relative to the file."""
    path = Path(path)
    data = read_toml(path, "scene file")
    scene = scene_from_dict(data, base_dir=path.parent, where=str(path))
    scene.path = path.resolve()
    return scene


def scene_from_dict(data: dict, base_dir=None, where: str = "scene") -> Scene:
    """A scene from a dict shaped like the TOML file (what tomllib gives); relative paths are resolved against
    `base_dir` (default: the current directory). `where` names the source in error messages."""
    base_dir = Path.cwd() if base_dir is None else Path(base_dir)
    if not isinstance(data, dict):
        raise ValueError(f"{where}: a scene must be a table of tables, got {type(data).__name__}")
    unknown = sorted(set(data) - set(TABLES))
    if unknown:
        raise ValueError(f"{where}: unknown table(s) {unknown}; allowed: {list(TABLES)}")
    source = copy.deepcopy(data)
    camera = _build(Camera, _table(data, "camera", where), f"{where}: [camera]")
    lights = _lights(data, where, base_dir, source)
    fibers = _fibers(_table(data, "fibers", where), f"{where}: [fibers]", base_dir, source)
    hair = _hair(_table(data, "hair", where), where)
    render = _build(RenderSettings, _table(data, "render", where, required=False), f"{where}: [render]")
    card = _build(Card, _table(data, "card", where), f"{where}: [card]") if "card" in data else None
    scene = Scene(camera, lights, fibers, hair, render, card, source)
    try:
        check_scene(scene)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    return scene


def check_scene(scene: Scene) -> None:
    """What the parts cannot check alone: float32 must resolve the fibers at the scene's extent, and the
    renderer's buffers must fit in memory (see warp_hair.validate). Strands that pass through each other, where
    renderers disagree, are a warning (once per assembly; warp_hair.geometry.interpenetration)."""
    validate.scene_scale(scene.fibers, scene.camera)
    validate.render_memory(scene.fibers.num_segments, scene.camera.resolution)
    warn_interpenetration(scene.fibers, scene.render.interpenetration)


def _table(data, name, where, required=True):
    if name not in data:
        if required:
            raise ValueError(f"{where}: the [{name}] table is missing")
        return {}
    table = data[name]
    if not isinstance(table, dict):
        raise ValueError(f"{where}: [{name}] must be a table, got {table!r}")
    return table


def _build(cls, table, prefix, **resolved):
    """cls(**table) after checking its keys, with `prefix` (file and table) on every error.

    `resolved` overrides table values the loader has already turned into something else (absolute paths).
    """
    accepted = [f.name for f in fields(cls) if f.init]
    _check_keys(table, accepted, prefix)
    required = [f.name for f in fields(cls) if f.init and f.default is MISSING and f.default_factory is MISSING]
    missing = [name for name in required if name not in table]
    if missing:
        raise ValueError(f"{prefix} missing key(s) {missing}")
    try:
        return cls(**{**table, **resolved})
    except ValueError as error:
        raise ValueError(f"{prefix} {error}") from None


def _check_keys(table, accepted, prefix):
    unknown = sorted(set(table) - set(accepted))
    if unknown:
        raise ValueError(f"{prefix} unknown key(s) {unknown}; allowed: {list(accepted)}")


def _lights(data, where, base_dir, source):
    tables = data.get("lights")
    if not tables:
        raise ValueError(f"{where}: no lights; add at least one [[lights]] table")
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise ValueError(f"{where}: lights must be an array of tables ([[lights]]), got {tables!r}")
    lights = [
        _light(table, f"{where}: [[lights]] #{k + 1}", base_dir, source["lights"][k]) for k, table in enumerate(tables)
    ]
    # The environment is what a path sees when it leaves the scene: there is one, or none.
    environments = [k + 1 for k, light in enumerate(lights) if isinstance(light, EnvironmentLight)]
    if len(environments) > 1:
        raise ValueError(
            f"{where}: [[lights]] #{environments[1]} is a second environment light; a scene has at most one"
        )
    return lights


def _light(table, prefix, base_dir, source):
    kinds = {"directional": DirectionalLight, "environment": EnvironmentLight}
    kind = table.get("type")
    if not isinstance(kind, str) or kind not in kinds:
        raise ValueError(f"{prefix} type must be one of {list(kinds)}, got {kind!r}")
    table = {key: value for key, value in table.items() if key != "type"}
    if kind == "environment" and "file" in table:
        path = _path(table["file"], base_dir, f"{prefix} file")
        source["file"] = str(path)
        return _build(EnvironmentLight, table, prefix, file=path)
    return _build(kinds[kind], table, prefix)


def _path(value, base_dir, name):
    """An absolute path from a file name in the scene, relative to `base_dir`."""
    if not isinstance(value, str) or not value:
        raise ValueError(f"{name} must be a file name, got {value!r}")
    path = (base_dir / value).resolve()
    if not path.is_file():
        raise ValueError(f"{name} not found: {path}")
    return path


def _fibers(table, prefix, base_dir, source):
    if ("file" in table) == ("generator" in table):
        raise ValueError(f"{prefix} needs exactly one of file (a .txt, .hair or USD file) and generator")
    usd = "file" in table and Path(str(table["file"])).suffix.lower() in USD_SUFFIXES
    curve = {} if usd else {key: table[key] for key in CURVE_OPTIONS if key in table}
    seed = table.get(RANDOM_SEED)
    table = {key: value for key, value in table.items() if key not in curve and key != RANDOM_SEED}
    if "file" in table:
        path = _path(table["file"], base_dir, f"{prefix} file")
        usd_options = USD_FIBER_OPTIONS if usd else []
        _check_keys(table, ["file", *usd_options], prefix)
        source["fibers"]["file"] = str(path)
        try:
            fibers = load_fibers(path, **{key: table[key] for key in usd_options if key in table})
        except (OSError, ValueError, ImportError) as error:
            raise ValueError(f"{prefix} file: {error}") from None
    else:
        fibers = _generate(table, prefix)
    if fibers.num_strands == 0:
        raise ValueError(f"{prefix} holds no strands")
    return _as_curve(_with_random_seed(fibers, seed, prefix), curve, prefix)


def _with_random_seed(fibers, seed, prefix):
    """The strands with their random values drawn from `random_seed` (None: left as they are)."""
    if seed is None:
        return fibers
    seed = validate.seed(f"{prefix} {RANDOM_SEED}", seed)
    if fibers.strand_random is not None:
        raise ValueError(f"{prefix} {RANDOM_SEED}: the file gives each strand its own random value; leave it out")
    return FiberAssembly(
        fibers.points, fibers.radii, fibers.strand_offsets, strand_random=strand_random(fibers.num_strands, seed)
    )


def _as_curve(fibers, options, prefix):
    """The strands as `curve` says (CURVE_KINDS): as they are, or the Catmull-Rom curve through their vertices."""
    kind = options.get("curve", "polyline")
    if kind not in CURVE_KINDS:
        raise ValueError(f"{prefix} curve must be one of {list(CURVE_KINDS)}, got {kind!r}")
    if "tolerance" in options and kind != "catmull-rom":
        raise ValueError(f'{prefix} tolerance applies to curve = "catmull-rom" (and to USD cubic curves)')
    if kind == "polyline":
        return fibers
    try:
        return catmull_rom(fibers, options.get("tolerance", DEFAULT_TOLERANCE))
    except ValueError as error:
        raise ValueError(f"{prefix} {error}") from None


def _generate(table, prefix):
    name = table["generator"]
    if not isinstance(name, str) or name not in GENERATORS:
        raise ValueError(f"{prefix} generator must be one of {list(GENERATORS)}, got {name!r}")
    generator = GENERATORS[name]
    args = {key: value for key, value in table.items() if key != "generator"}
    prefix = f"{prefix} generator {name!r}:"
    _check_keys(args, list(inspect.signature(generator).parameters), prefix)
    for key, value in args.items():
        _check_generator_arg(key, value, prefix)
    try:
        return generator(**args)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{prefix} {error}") from None


def _check_generator_arg(key, value, prefix):
    try:
        if key == "seed":
            validate.integer(key, value, minimum=0, maximum=None)
        elif key in INTEGER_GENERATOR_ARGS:
            validate.integer(key, value)
        elif key in PAIR_GENERATOR_ARGS and isinstance(value, (list, tuple)):
            if len(value) != 2:
                raise ValueError(f"{key} must be one number or two, got {value!r}")
            for v in value:
                validate.length(key, v)
        else:
            validate.real(key, value)
    except ValueError as error:
        raise ValueError(f"{prefix} {error}") from None


def _hair(table, where):
    # Keys checked here, not by from_dict, so that the message starts with the file like every other scene error.
    _check_keys(table, [*CONTROL_NAMES, ALBEDO_INVERSION_KEY], f"{where}: [hair]")
    table_where = f"{where} [hair]"
    try:
        return HairParams.from_dict(table, where=table_where)
    except ValueError as error:
        message = str(error)
        # The albedo inversion's checks name `where` themselves; the range checks of HairParams do not.
        raise ValueError(message if table_where in message else f"{where}: [hair] {message}") from None
