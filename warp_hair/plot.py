"""Lobe plots of the hair BSDF, for checking a material by eye.

The profiles are luminances of the four terms of S (R, TT, TRT, residual; `bsdf.eval_lobes`) in the local
frame of docs/MODEL.md. With h = None they are the far-field look, S averaged over the fiber offset h ∈ [−1, 1];
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
from matplotlib.ticker import NullLocator

from . import bsdf
from .model.params import HairParams

LOBE_NAMES = ("R", "TT", "TRT", "residual")
LOBE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

# The lobes depend on φ only through Δφ = φ_i − φ_o; any φ_o will do.
PHI_O = 0.5 * math.pi

# Evaluations per eval_lobes call: bounds the memory (48 bytes of output each) whatever the grid.
BATCH = 1 << 20

# Far field, azimuthal profile: S at each Δφ averages one logistic (scale s) per offset, centred at Φ_p(γ),
# γ = asin h, which moves by at most 2 radians per radian of γ. Offsets evenly spaced in γ with centres
# 1.5 s apart blend into a smooth curve (ripple ~ e^(−4π²/3)); sparser ones into a comb. The cap leaves a
# faint comb only below β_n ≈ 0.02.
CENTRES_PER_SCALE = 1.5
N_GAMMA_AZIMUTHAL = (64, 1024)
# Far field, longitudinal profile: at each offset ∫ S dφ_i = Σ_p M_p A_p(h), smooth in γ, so a
# Gauss-Legendre rule in γ converges fast: 16 nodes get the residual lobe, whose A_3 is the steepest near
# the edges, to 5e-5 (8 nodes miss it by 3%). Each offset's ∫ dφ_i is a periodic midpoint rule, exact to
# about 4πsn e^(−πsn) for a logistic of scale s on n nodes: n = 4/s gives 2e-4. The cap (for speed) costs
# up to 8% at one offset, less averaged over h, and only below β_n ≈ 0.015.
N_GAMMA_GAUSS = 16
PHI_PER_SCALE = 4.0
N_PHI = (64, 1024)
# The plots' log scales span this many decades below the peak: for light hair R and TRT are 10-100×
# weaker than TT, barely visible on a linear scale.
DECADES = 3
# Plot points: spacing s/2 in Δφ and σ/3 in θ_i (σ² the narrowest lobe variance), within these bounds. The
# caps are for speed: near the smallest β the narrowest peaks fall between points and read up to 25% low.
N_AZIMUTHAL = (721, 2049)
N_LONGITUDINAL = (181, 541)


def direction(theta, phi) -> np.ndarray:
    """Unit vectors (..., 3) of the local frame from θ (sin θ = w.x) and φ = atan2(w.z, w.y), in radians."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64))
    return np.stack([np.sin(theta), np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi)], axis=-1)


def _check_theta_o(theta_o_deg) -> float:
    theta_o = float(theta_o_deg)
    if not -90.0 < theta_o < 90.0:
        raise ValueError(f"theta_o = {theta_o_deg} is outside the allowed range (-90, 90) degrees")
    return math.radians(theta_o)


def _check_h(h) -> float:
    h = float(h)
    if not -1.0 <= h <= 1.0:
        raise ValueError(f"h = {h} is outside the allowed range [-1, 1]")
    return h


def _offsets(h: float | None, gamma: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fiber offsets to average and their weights (summing to 1): the one h given, or the far field.

    The far field averages over h ∈ [−1, 1] by a rule (nodes, weights) in γ = asin h, dh = cos γ dγ: in γ
    the square-root edges of A_p and of the lobe centres at h = ±1 are gone.
    """
    if h is not None:
        return np.array([_check_h(h)]), np.array([1.0])
    weights = weights * np.cos(gamma)
    return np.sin(gamma), weights / weights.sum()


def _midpoints(n: int, lo: float, hi: float) -> np.ndarray:
    return lo + (np.arange(n) + 0.5) * (hi - lo) / n


def _clamp(n: float, bounds: tuple[int, int]) -> int:
    return min(bounds[1], max(bounds[0], math.ceil(n)))


def _weighted_lobes(params: HairParams, wo: np.ndarray, theta, phi, h, weights: np.ndarray) -> np.ndarray:
    """Σ_k weights[k] · luminance of the lobe terms at wi = direction(θ[j, k], φ[j, k]), h[j, k], per row j.

    θ, φ and h broadcast to (rows, columns); weights are (columns,). Returns (rows, 4).
    """
    theta, phi, h = np.broadcast_arrays(np.asarray(theta, dtype=np.float64), np.asarray(phi, dtype=np.float64), h)
    rows, columns = theta.shape
    step = max(1, BATCH // columns)
    out = np.empty((rows, 4))
    for start in range(0, rows, step):
        block = slice(start, start + step)
        wi = direction(theta[block], phi[block]).reshape(-1, 3)
        luminance = bsdf.eval_lobes(params, wo, wi, h[block].ravel()) @ LUMINANCE
        out[block] = np.einsum("jkp,k->jp", luminance.reshape(-1, columns, 4), weights)
    return out


def azimuthal_profile(params: HairParams, theta_o_deg: float, h: float | None = None, n: int | None = None):
    """S in the specular cone θ_i = −θ_o as a function of Δφ = φ_i − φ_o.

    Returns Δφ (n,) from −π to π (radians; 0 is back toward the viewer, ±π forward through the fiber)
    and the luminance of each lobe (n, 4) in 1/sr. n = None picks enough points to resolve the lobes.
    """
    theta_o = _check_theta_o(theta_o_deg)
    s = params.logistic_scale
    if n is None:
        n = _clamp(4.0 * math.pi / s, N_AZIMUTHAL)
    n_gamma = _clamp(2.0 * math.pi / (CENTRES_PER_SCALE * s), N_GAMMA_AZIMUTHAL)
    gamma = _midpoints(n_gamma, -0.5 * math.pi, 0.5 * math.pi)
    hs, weights = _offsets(h, gamma, np.ones_like(gamma))
    dphi = np.linspace(-math.pi, math.pi, n)
    lobes = _weighted_lobes(params, direction(theta_o, PHI_O), -theta_o, (PHI_O + dphi)[:, None], hs, weights)
    return dphi, lobes


def longitudinal_profile(params: HairParams, theta_o_deg: float, h: float | None = None, n: int | None = None):
    """∫ S dφ_i over the full circle of azimuths as a function of θ_i.

    Returns θ_i (n,), midpoints of [−π/2, π/2] in radians, and the luminance of each lobe (n, 4) in 1/rad:
    ∫ (their sum) cos θ_i dθ_i is the directional albedo (1 with σ_a = 0). n = None picks enough points
    to resolve the narrowest lobe.
    """
    theta_o = _check_theta_o(theta_o_deg)
    if n is None:
        n = _clamp(3.0 * math.pi / math.sqrt(params.lobe_variances.min()), N_LONGITUDINAL)
    nodes, gauss_weights = np.polynomial.legendre.leggauss(N_GAMMA_GAUSS)
    hs, h_weights = _offsets(h, 0.5 * math.pi * nodes, gauss_weights)
    n_phi = _clamp(PHI_PER_SCALE / params.logistic_scale, N_PHI)
    phi = _midpoints(n_phi, PHI_O - math.pi, PHI_O + math.pi)
    # Columns are (azimuth j, offset k) pairs, k fastest.
    weights = np.outer(np.full(n_phi, 2.0 * math.pi / n_phi), h_weights).ravel()
    theta_i = _midpoints(n, -0.5 * math.pi, 0.5 * math.pi)
    wo = direction(theta_o, PHI_O)
    lobes = _weighted_lobes(params, wo, theta_i[:, None], np.repeat(phi, len(hs)), np.tile(hs, n_phi), weights)
    return theta_i, lobes


def _output_path(path) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"the output must be a .png file, got '{path}'")
    if not path.parent.is_dir():
        raise ValueError(f"cannot write '{path}': directory '{path.parent}' does not exist")
    if path.is_dir():
        raise ValueError(f"cannot write '{path}': it is a directory")
    return path


def _triple(values) -> str:
    return "(" + ", ".join(f"{v:.3g}" for v in values) + ")"


def _title(params: HairParams, h: float | None) -> str:
    sigma_a = f"σ_a = {_triple(params.absorption)} per fiber radius"
    if params.colour_input == "albedo":
        colour = f"albedo {_triple(params.albedo)}  →  {sigma_a}"
    elif params.colour_input == "melanin":
        colour = f"eumelanin {params.eumelanin:g}, pheomelanin {params.pheomelanin:g}  →  {sigma_a}"
    else:
        colour = sigma_a
    look = "far field: S averaged over h ∈ [−1, 1]" if h is None else f"fiber offset h = {h:g}"
    controls = (
        f"β_m = {params.beta_m:g}, β_n = {params.beta_n:g}, α = {params.alpha:g}°, η = {params.eta:g}, "
        f"R roughness scale {params.r_roughness_scale:g}"
    )
    return f"Hair BSDF lobes (luminance)   {colour}\n{controls}   |   {look}"


def _draw_lobes(ax, x, lobes: np.ndarray) -> float:
    """Plot each lobe and the total on a log scale cut DECADES below the peak; returns the cut."""
    total = lobes.sum(axis=1)
    floor = total.max() * 10.0**-DECADES
    for p, (name, colour) in enumerate(zip(LOBE_NAMES, LOBE_COLOURS)):
        ax.plot(x, np.maximum(lobes[:, p], floor), color=colour, lw=1.2, label=name)
    # The total goes underneath (lines sit at zorder 2), wide, so a lobe that is all of it still shows.
    ax.plot(x, np.maximum(total, floor), color="black", lw=2.6, zorder=1.5, label="total")
    return floor


def _draw_azimuthal(ax, dphi: np.ndarray, lobes: np.ndarray, theta_o: float) -> None:
    floor = _draw_lobes(ax, dphi, lobes)
    ax.set_rscale("log")
    ax.set_rlim(floor, None)
    ax.yaxis.set_minor_locator(NullLocator())  # rings at decades only
    ax.set_theta_zero_location("N")
    ticks = np.arange(-180, 180, 45)
    labels = [f"{t}°" for t in ticks]
    labels[0], labels[4] = "±180°\nforward", "0°\nback"
    ax.set_thetagrids(ticks % 360, labels, fontsize=8)
    ax.set_rlabel_position(67.5)
    ax.tick_params(axis="y", labelsize=7)
    for label in ax.get_yticklabels():
        label.set_bbox({"facecolor": "white", "alpha": 0.8, "edgecolor": "none", "pad": 0.3})
    heading = f"azimuthal, θ_o = {theta_o:g}°, θ_i = {-theta_o + 0.0:g}°"  # + 0.0 turns −0 into 0
    ax.set_title(f"{heading}\nS (1/sr, log radius) against Δφ = φ_i − φ_o", fontsize=10)


def _draw_longitudinal(ax, theta_i: np.ndarray, lobes: np.ndarray, theta_o: float) -> None:
    floor = _draw_lobes(ax, np.degrees(theta_i), lobes)
    ax.set_yscale("log")
    ax.axvline(-theta_o, color="0.35", ls=":", lw=1.2, label="mirror θ_i = −θ_o")
    ax.set_xlim(-90.0, 90.0)
    ax.set_xticks(np.arange(-90, 91, 30))
    ax.set_ylim(floor, None)
    ax.grid(alpha=0.3)
    ax.set_xlabel("θ_i (degrees)")
    ax.set_ylabel("∫ S dφ_i (1/rad)")
    ax.set_title(f"longitudinal, θ_o = {theta_o:g}°", fontsize=10)


def plot_lobes(params: HairParams, path, theta_o_deg=(0.0, 30.0, 60.0), h: float | None = None) -> Path:
    """Write a PNG of the azimuthal (top row) and longitudinal (bottom row) profiles, one column per θ_o."""
    path = _output_path(path)
    angles = [float(t) for t in np.atleast_1d(theta_o_deg)]
    if not angles:
        raise ValueError("theta_o_deg needs at least one angle")
    for theta_o in angles:
        _check_theta_o(theta_o)
    if h is not None:
        _check_h(h)

    fig = Figure(figsize=(12, 7), dpi=120, layout="constrained")
    columns = len(angles)
    for k, theta_o in enumerate(angles):
        polar = fig.add_subplot(2, columns, k + 1, projection="polar")
        _draw_azimuthal(polar, *azimuthal_profile(params, theta_o, h), theta_o)
        ax = fig.add_subplot(2, columns, columns + k + 1)
        _draw_longitudinal(ax, *longitudinal_profile(params, theta_o, h), theta_o)
    fig.suptitle(_title(params, h), fontsize=11)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=6, frameon=False)
    fig.savefig(path, format="png")
    return path
