"""Batch API of the hair BSDF over NumPy arrays, running the renderer's own Warp functions.

Directions are in the local frame of docs/MODEL.md (x along the fiber, z the normal at the hit), wo toward the
viewer, wi toward the light; h is the signed fiber offset in [−1, 1]. A single direction (3,) or a scalar h
broadcasts against the others. Results are float32, as the renderer computes them.

    S = eval(params, wo, wi, h)            # (N, 3) cosine-weighted value; ∫ S dω_i = directional albedo
    p = pdf(params, wo, wi, h)             # (N,) solid-angle density of `sample`
    wi, weight, p = sample(params, wo, h, u)   # u (N, 3) uniforms in [0, 1); weight = S / pdf
    lobes = eval_lobes(params, wo, wi, h)  # (N, 4, 3): the R, TT, TRT and residual terms of S
    A = attenuation(params, wo, h)         # (N, 4, 3): A_p per lobe

A kernel of one's own over the same inputs (the derivative checks' in tests/helpers/bsdf_grad.py) takes the same
checks and launch: `check_params`, `check_directions`, `check_offsets`, then `launch_batch`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..numerics import FLOAT32_MIN_NORMAL
from ..parallel import launch_ranges
from .hair_bsdf import (
    HairCoefficients,
    hair_coefficients,
    hair_pdf,
    hair_sample,
    hair_value,
    hair_value_pdf,
    incident_angles,
    lobe_densities,
    lobe_setup,
)
from .params import HairParams

# The batch API only runs forward; gradients have their own kernels.
wp.set_module_options({"enable_backward": False})

UNIT_TOLERANCE = 1e-4


@wp.kernel
def _eval_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    out[i] = hair_value(lobe_setup(c, wo[i], h[i]), wi[i])


@wp.kernel
def _pdf_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array(dtype=float),
    first: int,
):
    i = wp.tid() + first
    out[i] = hair_pdf(lobe_setup(c, wo[i], h[i]), wi[i])


@wp.kernel
def sample_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    u: wp.array(dtype=wp.vec3),
    wi_out: wp.array(dtype=wp.vec3),
    weight_out: wp.array(dtype=wp.vec3),
    pdf_out: wp.array(dtype=float),
    first: int,
):
    i = wp.tid() + first
    L = lobe_setup(c, wo[i], h[i])
    wi = hair_sample(L, u[i])
    # At the returned direction (not the sample's own angles, as the renderer does): pdf(wi) of what is returned.
    value, density = hair_value_pdf(L, wi)
    weight = wp.vec3(0.0)
    # A direction whose density underflowed (the far tail of a very narrow lobe) carries no weight rather than
    # an imprecise ratio of subnormals, or 0/0, as in the renderer.
    if density >= FLOAT32_MIN_NORMAL:
        weight = value / density
    wi_out[i] = wi
    weight_out[i] = weight
    pdf_out[i] = density


@wp.kernel
def _lobes_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    wi: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array2d(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    L = lobe_setup(c, wo[i], h[i])
    sin_i, cos_i, dphi = incident_angles(L, wi[i])
    d = lobe_densities(L, sin_i, cos_i, dphi)
    for p in range(4):
        out[i, p] = d[p] * L.A[p]


@wp.kernel
def _attenuation_kernel(
    c: HairCoefficients,
    wo: wp.array(dtype=wp.vec3),
    h: wp.array(dtype=float),
    out: wp.array2d(dtype=wp.vec3),
    first: int,
):
    i = wp.tid() + first
    L = lobe_setup(c, wo[i], h[i])
    for p in range(4):
        out[i, p] = L.A[p]


def _numeric(name: str, value) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numeric, got {type(value).__name__}") from None
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name} contains NaN or Inf (first at index {tuple(int(i) for i in bad)})")
    return arr


def _vectors(name: str, value) -> np.ndarray:
    arr = _numeric(name, value)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3) or (3,), got {np.shape(value)}")
    return arr


def check_directions(name: str, value) -> np.ndarray:
    """`value` as an (N, 3) float64 array of unit vectors, else a ValueError naming `name`."""
    arr = _vectors(name, value)
    norm = np.linalg.norm(arr, axis=1)
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    if np.any(off):
        k = int(np.argmax(off))
        raise ValueError(
            f"{name} must hold unit vectors (|w| within {UNIT_TOLERANCE} of 1); {name}[{k}] has length {norm[k]:.6g}"
        )
    return arr


def check_offsets(value) -> np.ndarray:
    """The fiber offsets h as an (N,) float64 array in [−1, 1], else a ValueError."""
    arr = _numeric("h", value)
    if arr.ndim > 1:
        raise ValueError(f"h must be a scalar or have shape (N,), got {arr.shape}")
    arr = np.atleast_1d(arr)
    outside = np.abs(arr) > 1.0
    if np.any(outside):
        k = int(np.argmax(outside))
        raise ValueError(f"h must lie in [-1, 1]; h[{k}] = {arr[k]}")
    return arr


def _uniforms(value) -> np.ndarray:
    arr = _vectors("u", value)
    outside = (arr < 0.0) | (arr >= 1.0)
    if np.any(outside):
        k = tuple(int(i) for i in np.argwhere(outside)[0])
        raise ValueError(f"u must lie in [0, 1); u[{k[0]}, {k[1]}] = {arr[k]}")
    return arr


def _broadcast(**arrays: np.ndarray) -> tuple[int, dict]:
    """Broadcast per-item inputs (leading axis 1 or N) to a common N, naming the culprit if they disagree."""
    sizes = {name: a.shape[0] for name, a in arrays.items()}
    n = max(sizes.values())
    for name, size in sizes.items():
        if size not in (1, n):
            others = ", ".join(f"{k}: {v}" for k, v in sizes.items())
            raise ValueError(f"inputs have different lengths ({others}); {name} must have length 1 or {n}")
    return n, {name: np.broadcast_to(a, (n, *a.shape[1:])) for name, a in arrays.items()}


def check_params(params) -> HairCoefficients:
    """The model coefficients of a HairParams; a TypeError for anything else."""
    if not isinstance(params, HairParams):
        raise TypeError(f"params must be a warp_hair.HairParams, got {type(params).__name__}")
    return hair_coefficients(params)


def _to_warp(a: np.ndarray, dtype, device: str):
    return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=device)


# The Warp type of each checked per-item input, by name.
_WARP_TYPES = {"wo": wp.vec3, "wi": wp.vec3, "h": float, "u": wp.vec3}


def launch_batch(kernel, leading: list, items: dict, outputs: list, threads, device) -> list:
    """Broadcast the checked per-item inputs `items` (name → array), launch
    `kernel(*leading, *items, *outputs, first)` over all cores and return the outputs as NumPy arrays.
    `outputs` holds (shape per item, Warp dtype) pairs."""
    n, a = _broadcast(**items)
    outs = [wp.empty((n, *shape), dtype=dtype, device=device) for shape, dtype in outputs]
    inputs = [*leading, *(_to_warp(a[name], _WARP_TYPES[name], device) for name in items), *outs]
    launch_ranges(kernel, n, inputs, threads, device)
    return [out.numpy() for out in outs]


def eval(params: HairParams, wo, wi, h, threads: int | None = None, device: str = "cpu") -> np.ndarray:
    """S(wo, wi, h) per item, RGB: the cosine-weighted value (pbrt's f·|cos θ_i|, Mitsuba's eval)."""
    items = {"wo": check_directions("wo", wo), "wi": check_directions("wi", wi), "h": check_offsets(h)}
    return launch_batch(_eval_kernel, [check_params(params)], items, [((), wp.vec3)], threads, device)[0]


def pdf(params: HairParams, wo, wi, h, threads: int | None = None, device: str = "cpu") -> np.ndarray:
    """The solid-angle density with which `sample` draws wi."""
    items = {"wo": check_directions("wo", wo), "wi": check_directions("wi", wi), "h": check_offsets(h)}
    return launch_batch(_pdf_kernel, [check_params(params)], items, [((), float)], threads, device)[0]


def sample(params: HairParams, wo, h, u, threads: int | None = None, device: str = "cpu"):
    """Importance-sample wi; returns (wi (N, 3), weight = S/pdf (N, 3), pdf (N,)).

    u[:, 0] chooses the lobe (and its remainder the rotation about the longitudinal cone), u[:, 1] the
    longitudinal angle, u[:, 2] the azimuth.
    """
    items = {"wo": check_directions("wo", wo), "h": check_offsets(h), "u": _uniforms(u)}
    outputs = [((), wp.vec3), ((), wp.vec3), ((), float)]
    wi, weight, density = launch_batch(sample_kernel, [check_params(params)], items, outputs, threads, device)
    return wi, weight, density


def eval_lobes(params: HairParams, wo, wi, h, threads: int | None = None, device: str = "cpu") -> np.ndarray:
    """The four terms of S (R, TT, TRT, residual), shape (N, 4, 3); they sum to `eval`."""
    items = {"wo": check_directions("wo", wo), "wi": check_directions("wi", wi), "h": check_offsets(h)}
    return launch_batch(_lobes_kernel, [check_params(params)], items, [((4,), wp.vec3)], threads, device)[0]


def attenuation(params: HairParams, wo, h, threads: int | None = None, device: str = "cpu") -> np.ndarray:
    """A_p of each lobe (R, TT, TRT, residual), shape (N, 4, 3); with σ_a = 0 they sum to 1."""
    items = {"wo": check_directions("wo", wo), "h": check_offsets(h)}
    return launch_batch(_attenuation_kernel, [check_params(params)], items, [((4,), wp.vec3)], threads, device)[0]
