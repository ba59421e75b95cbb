"""Lobe plots of the hair BSDF, for checking a material by eye.

The profiles are luminances of the four terms of S (R, TT, TRT, residual; `bsdf.eval_lobes`) in the local
frame of MODEL.md. With h = None they are the far-field look, S averaged over the fiber offset h ∈ [−1, 1];
otherwise S at that one offset.

    dphi, lobes = azimuthal_profile(params, theta_o_deg)       # S at θ_i = −θ_o against Δφ = φ_i − φ_o
    theta_i, lobes = longitudinal_profile(params, theta_o_deg) # ∫ S dφ_i against θ_i
    plot_lobes(params, "lobes.png")                            # both, for several θ_o, as a PNG
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from . import bsdf
from .params import HairParams

LOBE_NAMES = ("R", "TT", "TRT", "residual")
LOBE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

# The viewer sits on the normal side of the fiber; the lobes depend on φ only through Δφ = φ_i − φ_o.
PHI_O = 0.5 * math.pi

# Per batch of evaluations: bounds the memory of one eval_lobes call (48 bytes of output per item).
BATCH = 1 << 20

# Offsets for the far field: A_p is smooth in γ = asin h, so a few dozen midpoints in γ integrate it.
N_GAMMA = 64
# The lobe centres move by at most 2 radians of Δφ per radian of γ; the azimuthal profile needs the grid of
# centres finer than the logistic scale s or its curves become a comb of one peak per offset. The cap keeps
# β_n below about 0.03 affordable, where that comb starts to show.
N_GAMMA_AZIMUTHAL_MAX = 1024
# Azimuths per ∫ dφ_i: the periodic midpoint rule is exact to about e^(−π s n) on a logistic of scale s,
# so n ≥ 8/s gives e^(−25). The cap on φ × h evaluations per θ_i keeps small β_n affordable; the offsets'
# moving centres average out most of what the coarser rule then misses.
PHI_PER_SCALE = 8.0
N_PHI_MIN = 64
N_PHI_H_MAX = 1 << 15


def direction(theta, phi) -> np.ndarray:
    """Unit vectors (..., 3) of the local frame from θ (sin θ = w.x) and φ = atan2(w.z, w.y), in radians."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64))
    return np.stack([np.sin(theta), np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi)], axis=-1)


def _check_theta_o(theta_o_deg) -> float:
    theta_o = float(theta_o_deg)
    if not -90.0 < theta_o < 90.0:
        raise ValueError(f"theta_o = {theta_o_deg} is outside the allowed range (-90, 90) degrees")
    return math.radians(theta_o)


def offsets(h: float | None, n_gamma: int = N_GAMMA) -> tuple[np.ndarray, np.ndarray]:
    """Fiber offsets and their quadrature weights (summing to 1): the one given, or the far-field average.

    The average over h ∈ [−1, 1] is taken in γ = asin h (dh = cos γ dγ), which removes the square-root
    edges of A_p and of the lobe centres at h = ±1 and spaces the centres evenly.
    """
    if h is not None:
        h = float(h)
        if not -1.0 <= h <= 1.0:
            raise ValueError(f"h = {h} is outside the allowed range [-1, 1]")
        return np.array([h]), np.array([1.0])
    gamma = (np.arange(n_gamma) + 0.5) * math.pi / n_gamma - 0.5 * math.pi
    weights = np.cos(gamma)
    return np.sin(gamma), weights / weights.sum()


def _weighted_lobes(params: HairParams, wo: np.ndarray, wi: np.ndarray, h: np.ndarray, weights: np.ndarray):
    """Σ_k weights[k] · luminance of the lobe terms at (wi[j, k], h[k]) for each row j: shape (rows, 4).

    wi is (rows, *columns, 3), usually a broadcast view; h and weights broadcast against the columns.
    Rows go to eval_lobes in batches, so only a batch of wi is ever materialised.
    """
    rows, columns = wi.shape[0], wi.shape[1:-1]
    h = np.broadcast_to(h, columns)
    weights = np.broadcast_to(weights, columns).ravel()
    step = max(1, BATCH // weights.size)
    out = np.empty((rows, 4))
    for start in range(0, rows, step):
        block = wi[start : start + step]
        block_h = np.broadcast_to(h, block.shape[:-1])
        lobes = bsdf.eval_lobes(params, wo, block.reshape(-1, 3), block_h.ravel())
        luminance = (lobes @ LUMINANCE).reshape(len(block), weights.size, 4)
        out[start : start + step] = np.einsum("jkp,k->jp", luminance, weights)
    return out


def azimuthal_profile(params: HairParams, theta_o_deg: float, h: float | None = None, n: int = 721):
    """S in the specular cone θ_i = −θ_o as a function of Δφ = φ_i − φ_o.

    Returns Δφ (n,) from −π to π (radians; 0 is back toward the viewer, ±π forward through the fiber)
    and the luminance of each lobe (n, 4) in 1/sr.
    """
    theta_o = _check_theta_o(theta_o_deg)
    n_gamma = min(N_GAMMA_AZIMUTHAL_MAX, max(N_GAMMA, math.ceil(4.0 * math.pi / params.logistic_scale)))
    hs, weights = offsets(h, n_gamma)
    dphi = np.linspace(-math.pi, math.pi, n)
    wi = np.broadcast_to(direction(-theta_o, PHI_O + dphi)[:, None, :], (n, len(hs), 3))
    return dphi, _weighted_lobes(params, direction(theta_o, PHI_O), wi, hs, weights)


def longitudinal_profile(params: HairParams, theta_o_deg: float, h: float | None = None, n: int = 181):
    """∫ S dφ_i over the full circle of azimuths as a function of θ_i.

    Returns θ_i (n,), midpoints of [−π/2, π/2] in radians, and the luminance of each lobe (n, 4) in 1/rad;
    ∫ (its sum) cos θ_i dθ_i is the directional albedo (1 with σ_a = 0).
    """
    theta_o = _check_theta_o(theta_o_deg)
    hs, h_weights = offsets(h)
    n_phi = max(N_PHI_MIN, math.ceil(PHI_PER_SCALE / params.logistic_scale))
    n_phi = min(n_phi, max(N_PHI_MIN, N_PHI_H_MAX // len(hs)))
    phi = PHI_O - math.pi + (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi
    theta_i = (np.arange(n) + 0.5) * math.pi / n - 0.5 * math.pi
    wi = np.broadcast_to(direction(theta_i[:, None, None], phi[None, :, None]), (n, n_phi, len(hs), 3))
    weights = np.outer(np.full(n_phi, 2.0 * math.pi / n_phi), h_weights)
    return theta_i, _weighted_lobes(params, direction(theta_o, PHI_O), wi, hs, weights)
