"""Calibrate the albedo inversion for an assembly and its lighting: `warp-hair calibrate SCENE.toml`.

The albedo control stands for an absorption through the talk's inversion σ_a = (ln c / P(β_n))², P a degree-5
polynomial that Chiang et al. fitted to brute-force renders of a dense block of fibers. Whether a requested
albedo c is what an image shows depends on the assembly (how dense, how deep) and on the light, so this module
measures it with the renderer and refits P:

1. render the scene at every point of a grid of grey σ_a and β_n (its other controls as they are);
2. measure the albedo of each render: the mean over the measured pixels of the image, over the radiance a white
   Lambertian card facing the camera would show under the scene's lights (for a uniform sky of radiance L, that
   is L). The measured pixels are those in which every one of a 4×4 grid of camera rays hits a fiber: the
   assembly hides the background there;
3. fit ln c = −sqrt(σ_a) · P(β_n) by weighted linear least squares in the six coefficients of P (weights: the
   standard error of ln c, from each pixel's sample spread), and report each point's residual.

The result goes into a scene's ``[hair.albedo_inversion] coefficients = [p_0, ..., p_5]`` table, which
`HairParams` uses wherever it turns albedo into σ_a (the renderer, the derivatives, the fit's latents).

    result = calibrate(scene, sigma_a=[0.002, 0.01, 0.05, 0.2], beta_n=[0.02, 0.2, 0.4, 0.6, 0.8, 1.0])
    result.coefficients, result.table(), inversion_toml(result.coefficients)

`block_scene` builds the talk's setup, a dense block of parallel fibers under a uniform white sky seen head-on
over a black card (benchmarks/albedo_inversion.py measures the talk's inversion on it).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from .geometry.rays import occluded
from .geometry.tubes import FiberBVH
from .model.params import (
    ALBEDO_INVERSION_DEGREE,
    ALBEDO_INVERSION_KEY,
    ALBEDO_INVERSION_RANGE,
    HairParams,
    check_albedo_inversion,
    effective_beta,
)
from .renderer.camera import camera_rays
from .renderer.render import render
from .scene import DirectionalLight, EnvironmentLight, Scene, scene_from_dict

DEFAULT_SIGMA_A = (0.002, 0.01, 0.04, 0.12, 0.35)
DEFAULT_BETA_N = (0.02, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9, 1.0)
# Camera rays per pixel side that must all hit a fiber for the pixel to be measured.
COVERAGE_RAYS = 4
# Paths in a dense block of light hair are long: at albedo 0.8 a depth limit of 64 loses about 10 % of the
# light (benchmarks/albedo_inversion.py --max-depth 64); Russian roulette keeps the cost of a deeper limit low.
BLOCK_MAX_DEPTH = 1024


def block_scene(
    hair: HairParams,
    layers: int = 40,
    per_layer: int = 327,
    length: float = 8.0,
    view: float = 0.5,
    resolution: int = 32,
    spp: int = 256,
    max_depth: int = BLOCK_MAX_DEPTH,
) -> Scene:
    """The talk's calibration setup: a block of `layers` layers of `per_layer` straight parallel fibers (the
    `swatch` generator's defaults otherwise: radius 0.004, spacing 0.0122, no two fibers touching; 327 span about
    4 units across x), `length` along y, fibers along y listed root first, under a uniform white sky (radiance 1),
    over a black card, seen head-on by an orthographic camera `view` wide at the block's centre, far from its
    sides and ends."""
    scene = scene_from_dict(
        {
            "camera": {
                "type": "orthographic",
                "origin": [0.0, 0.0, 2.0],
                "target": [0.0, 0.0, 0.0],
                "up": [0.0, 1.0, 0.0],
                "width": view,
                "resolution": [resolution, resolution],
            },
            "lights": [{"type": "environment", "radiance": [1.0, 1.0, 1.0]}],
            "fibers": {
                "generator": "swatch",
                "count": layers * per_layer,
                "layers": layers,
                "length": length,
                "segments": 1,
            },
            "hair": {"sigma_a": 0.0},
            "card": {"albedo": [0.0, 0.0, 0.0]},
            "render": {"spp": spp, "max_depth": max_depth},
        },
        where="block_scene",
    )
    return dataclasses.replace(scene, hair=hair)


def white_radiance(scene: Scene) -> np.ndarray:
    """RGB radiance of a white Lambertian card facing the camera under the scene's lights: (1/π) ∫ L cos."""
    forward = scene.camera.frame()[0]
    normal = -forward
    total = np.zeros(3)
    for light in scene.lights:
        if isinstance(light, DirectionalLight):
            cosine = max(0.0, -float(np.dot(light.direction, normal)))
            total += np.asarray(light.irradiance) * cosine / math.pi
        elif isinstance(light, EnvironmentLight) and light.image is None:
            total += np.asarray(light.radiance)
        elif isinstance(light, EnvironmentLight):
            total += environment_white(light.image, normal)
    return total


def environment_white(image: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(1/π) ∫ L(ω) max(0, ω·n) dω over a lat-long image, cell by cell (envmap.py's convention)."""
    height, width = image.shape[:2]
    theta = math.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * math.pi * (np.arange(width) + 0.5) / width
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(p) * np.sin(t), np.cos(t), -np.cos(p) * np.sin(t)], axis=-1)
    solid_angle = (2.0 * math.pi / width) * (math.pi / height) * np.sin(t)
    weight = np.maximum(0.0, d @ normal) * solid_angle / math.pi
    return np.einsum("hw,hwc->c", weight, image.astype(np.float64))


def measured_pixels(scene: Scene) -> np.ndarray:
    """(H, W) bool: the pixels in which every one of COVERAGE_RAYS² stratified camera rays hits a fiber."""
    width, height = scene.camera.resolution
    py, px = np.mgrid[0:height, 0:width]
    offsets = (np.arange(COVERAGE_RAYS) + 0.5) / COVERAGE_RAYS
    jitter = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2)
    shape = (height, width, len(jitter))
    px, py = np.broadcast_to(px[..., None], shape), np.broadcast_to(py[..., None], shape)
    origins, directions = camera_rays(scene.camera, px, py, np.broadcast_to(jitter, (*shape, 2)))
    hit = occluded(FiberBVH(scene.fibers), origins.reshape(-1, 3), directions.reshape(-1, 3))
    return hit.reshape(height, width, -1).all(axis=-1)


def measure_albedo(scene: Scene, mask: np.ndarray, white: np.ndarray, spp=None, seed=None, threads=None):
    """(albedo, standard error) of one render: the mean over `mask` of the image over `white` (channels summed).

    A pixel's channels share their paths, so their errors add (the sum of their standard errors bounds it).
    """
    image, stderr = render(scene, spp=spp, seed=seed, threads=threads, return_stderr=True)
    scale = float(np.sum(white))
    values = image.astype(np.float64).sum(axis=-1)[mask] / scale
    errors = stderr.astype(np.float64).sum(axis=-1)[mask] / scale
    return float(values.mean()), float(math.sqrt(np.sum(errors**2)) / values.size)


def fit_inversion(sigma_a, beta_n, albedo, stderr=None) -> tuple:
    """The coefficients p_0 ... p_5 of P that fit ln c = −sqrt(σ_a) P(β_n) best in least squares, weighted by
    1 / (standard error of ln c) when `stderr` (of c) is given. β_n is floored as the model renders it."""
    sigma_a, beta_n, albedo = (np.asarray(x, dtype=np.float64).ravel() for x in (sigma_a, beta_n, albedo))
    if not (sigma_a.shape == beta_n.shape == albedo.shape):
        raise ValueError("sigma_a, beta_n and albedo must have one value per render")
    if np.any(sigma_a <= 0) or np.any(albedo <= 0) or np.any(albedo >= 1):
        raise ValueError("the fit needs σ_a > 0 and albedo in (0, 1) at every point")
    b = effective_beta(beta_n)
    design = np.sqrt(sigma_a)[:, None] * b[:, None] ** np.arange(ALBEDO_INVERSION_DEGREE + 1)
    target = -np.log(albedo)
    weights = np.ones_like(target) if stderr is None else albedo / np.asarray(stderr, dtype=np.float64).ravel()
    if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
        raise ValueError("every standard error must be positive and finite")
    coefficients, _, rank, _ = np.linalg.lstsq(design * weights[:, None], target * weights, rcond=None)
    if rank < ALBEDO_INVERSION_DEGREE + 1:
        raise ValueError(
            f"the grid does not determine P: a degree-{ALBEDO_INVERSION_DEGREE} polynomial in β_n needs at least "
            f"{ALBEDO_INVERSION_DEGREE + 1} distinct β_n values (got {len(np.unique(b))})"
        )
    return tuple(float(p) for p in coefficients)


def predicted_albedo(sigma_a, beta_n, coefficients) -> np.ndarray:
    """c = exp(−sqrt(σ_a) P(β_n)): the albedo the inversion assigns to σ_a at β_n."""
    b = effective_beta(np.asarray(beta_n, dtype=np.float64))
    return np.exp(-np.sqrt(np.asarray(sigma_a, dtype=np.float64)) * np.polynomial.polynomial.polyval(b, coefficients))


@dataclasses.dataclass
class Calibration:
    """The grid's measurements (one entry per render), the fitted coefficients and the fit's residuals."""

    sigma_a: np.ndarray
    beta_n: np.ndarray
    albedo: np.ndarray
    stderr: np.ndarray
    coefficients: tuple
    pixels: int

    @property
    def fitted(self) -> np.ndarray:
        return predicted_albedo(self.sigma_a, self.beta_n, self.coefficients)

    @property
    def z(self) -> np.ndarray:
        """Residuals in standard errors: (measured − fitted) / stderr."""
        return (self.albedo - self.fitted) / self.stderr

    @property
    def chi2_per_dof(self) -> float:
        dof = self.albedo.size - len(self.coefficients)
        return float(np.sum(self.z**2) / dof) if dof > 0 else math.nan

    def summary(self) -> str:
        residual = self.albedo - self.fitted
        return (
            f"coefficients p_0..p_5 of P(beta_n): {', '.join(f'{p:.6g}' for p in self.coefficients)}\n"
            f"residuals: rms {np.sqrt(np.mean(residual**2)):.4f}, largest {np.max(np.abs(residual)):.4f} in albedo; "
            f"chi2/dof {self.chi2_per_dof:.2f} (about 1 when P fits within the noise)"
        )

    def table(self) -> str:
        lines = [f"{'σ_a':>8} {'β_n':>5} {'measured':>17} {'fitted':>8} {'residual':>9} {'/σ':>6}"]
        for s, b, c, e, f, z in zip(self.sigma_a, self.beta_n, self.albedo, self.stderr, self.fitted, self.z):
            lines.append(f"{s:8.4g} {b:5.2f} {c:8.4f} ± {e:6.4f} {f:8.4f} {c - f:+9.4f} {z:+6.2f}")
        return "\n".join(lines)


def check_grid(sigma_a, beta_n) -> tuple:
    """(σ_a values, β_n values) as tuples of floats, or a ValueError naming the bad option and value."""
    sigma_a = tuple(float(s) for s in sigma_a)
    beta_n = tuple(float(b) for b in beta_n)
    for s in sigma_a:
        if not (math.isfinite(s) and s > 0):
            raise ValueError(
                f"--sigma-a {s:g}: grid values must be finite and > 0 (σ_a = 0 gives albedo 1, which "
                "says nothing about P)"
            )
    lo, hi = ALBEDO_INVERSION_RANGE
    for b in beta_n:
        if not lo <= b <= hi:
            raise ValueError(f"--beta-n {b:g} is outside the allowed range [{lo}, {hi}]")
    if len(set(beta_n)) < ALBEDO_INVERSION_DEGREE + 1:
        raise ValueError(
            f"--beta-n needs at least {ALBEDO_INVERSION_DEGREE + 1} distinct values to fit a degree-"
            f"{ALBEDO_INVERSION_DEGREE} polynomial, got {len(set(beta_n))}"
        )
    if len(set(sigma_a)) != len(sigma_a) or len(set(beta_n)) != len(beta_n):
        raise ValueError("--sigma-a and --beta-n must not repeat a value")
    return sigma_a, beta_n


def measure_points(scene: Scene, points, spp=None, seed=None, threads=None, progress=None):
    """(albedo, stderr), arrays with one entry per (σ_a, β_n) of `points`: the scene rendered with grey σ_a and
    that β_n (render k with seed + k), measured as the module docstring says."""
    seed = scene.render.seed if seed is None else int(seed)
    mask = measured_pixels(scene)
    if not mask.any():
        raise ValueError(
            "no pixel of the image is covered by fibers everywhere: calibrate measures the albedo "
            "where the assembly hides the background; frame the camera on it"
        )
    white = white_radiance(scene)
    if not np.sum(white) > 0:
        raise ValueError(
            "the lights give no light to a surface facing the camera; nothing to measure the albedo against"
        )
    measured = []
    for k, (s, b) in enumerate(points):
        moved = dataclasses.replace(scene, hair=scene.hair.replace(sigma_a=[s, s, s], beta_n=b))
        c, e = measure_albedo(moved, mask, white, spp=spp, seed=seed + k, threads=threads)
        if not 0.0 < c < 1.0 or not e > 0.0:
            raise ValueError(
                f"at σ_a = {s:g}, β_n = {b:g} the measured albedo is {c:.4g} ± {e:.2g}, which the inversion's "
                "c = exp(−sqrt(σ_a) P(β_n)) cannot give (it needs 0 < c < 1 and some noise): light the assembly as "
                "the calibration assumes, e.g. a uniform white sky, and keep σ_a > 0"
            )
        measured.append((c, e))
        if progress is not None:
            progress(k + 1, len(points))
    albedo, stderr = np.array(measured).T
    return albedo, stderr


def calibrate(
    scene: Scene, sigma_a=DEFAULT_SIGMA_A, beta_n=DEFAULT_BETA_N, spp=None, seed=None, threads=None, progress=None
) -> Calibration:
    """Render the grid (σ_a × β_n, grey σ_a, render k with seed + k), measure each albedo, fit P; see the module
    docstring. `progress(done, total)` counts renders. Raises ValueError when nothing can be measured, a
    measured albedo lies outside (0, 1), or the fitted P is not positive over [0.01, 1]."""
    sigma_a, beta_n = check_grid(sigma_a, beta_n)
    points = [(s, b) for b in beta_n for s in sigma_a]
    albedo, stderr = measure_points(scene, points, spp=spp, seed=seed, threads=threads, progress=progress)
    s_values, b_values = np.array(points).T
    coefficients = fit_inversion(s_values, b_values, albedo, stderr)
    try:
        check_albedo_inversion(coefficients, "the fitted albedo_inversion")
    except ValueError as error:
        raise ValueError(
            f"{error}; the grid's β_n do not pin P down over [0.01, 1]: add β_n values nearer the "
            "ends of that range or more σ_a values"
        ) from None
    return Calibration(s_values, b_values, albedo, stderr, coefficients, int(measured_pixels(scene).sum()))


def inversion_toml(coefficients) -> str:
    """The scene-file table that sets the inversion, for pasting into a scene's [hair]."""
    values = ", ".join(repr(float(p)) for p in coefficients)
    return f"[hair.{ALBEDO_INVERSION_KEY}]\ncoefficients = [{values}]\n"


def write_calibrated_scene(scene_path, output, coefficients) -> Path:
    """A copy of the scene file at `output` with [hair.albedo_inversion] set (comments and layout kept; relative
    file paths rewritten for the copy's folder). Refuses to write over the scene file itself."""
    import tomlkit

    scene_path, output = Path(scene_path), Path(output)
    check_copy_path(scene_path, output)
    document = tomlkit.parse(scene_path.read_text(encoding="utf-8"))
    for table in [document.get("fibers", {}), *document.get("lights", [])]:
        if isinstance(table.get("file"), str):
            table["file"] = _relocated(table["file"], scene_path.parent, output.parent)
    inversion = tomlkit.table()
    inversion["coefficients"] = [float(p) for p in coefficients]
    document["hair"][ALBEDO_INVERSION_KEY] = inversion
    try:
        output.write_text(tomlkit.dumps(document), encoding="utf-8")
    except OSError as error:
        raise OSError(f"-o {output}: cannot write the scene copy: {error.strerror or error}") from None
    return output


def check_copy_path(scene_path, output) -> None:
    """A ValueError if `output` is the scene file itself: calibrate never overwrites the user's scene."""
    if Path(output).resolve() == Path(scene_path).resolve():
        raise ValueError(f"-o {output} is the scene file itself; calibrate never overwrites it: give another file")


def _relocated(name: str, old_dir: Path, new_dir: Path) -> str:
    if Path(name).is_absolute():
        return name
    return os.path.relpath((old_dir / name).resolve(), new_dir.resolve())
