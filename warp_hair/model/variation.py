"""Hair as it grows: each strand's own look (strand-to-strand spread) and the change from root to tip.

    u = strand_random(num_strands, seed)          # each strand's random value in [0, 1], as Cycles draws it
    looks = strand_looks(params, u)               # σ_a, β_m, β_n per strand and their derivatives (float64)
    g = tip_profile(t, tip_absorption, tip_length)   # the absorption's factor at arc-length fraction t

The controls (table in `warp_hair.controls`; docs/MODEL.md, "Strand-to-strand and root-to-tip variation"):

- A strand's random value u is Cycles' per-curve `Random` (Blender 4.5 Cycles source, util/hash.h
  `hash_uint2_to_float(curve index, 0)`, which is what Blender gives a hair curve's random attribute): Bob
  Jenkins' lookup3 `final` mix of (index, seed), divided by 2³² − 1 in float32. A scene's strands with seed 0
  draw the very values Cycles gives the same curves, so a look exported to Cycles varies strand by strand as here.
- `roughness_spread` r: β_m and β_n of a strand are β·(1 + 2(u − ½)·r), as Cycles' `Random Roughness`
  (svm/closure.h, the Principled Hair case), clamped to [0, 1] (Cycles clamps to [0.001, 1]; below the floor of
  0.01 ours renders the floor, as everywhere). An albedo look inverts its colour at the strand's own β_n, as
  Cycles inverts its `Color` at the randomised `Radial Roughness`.
- `color_spread` c, factor f = 1 + 2(u − ½)·c:
  - a melanin look as Cycles' `Random Color` does, on its perceptual melanin: with M the total melanin in Cycles'
    units (its coefficients, kernel/closure/bsdf_util.h, are CYCLES_MELANIN_UNITS times d'Eon's, which ours use),
    m = 1 − e^(−M), the strand's melanin is −ln(max(1 − f·m, 10⁻⁴)), the red share kept;
  - an albedo or σ_a look: its σ_a times f (Cycles randomises only the melanin parametrisation).
- `tip_absorption` a and `tip_length` L: the absorption at arc-length fraction t from the root is the strand's
  times g(t) = 1 + (a − 1)·clamp((t − (1 − L)) / L, 0, 1): the root's up to 1 − L, a times it at the tip.

Where a clamp holds a strand's value, its derivative in the controls is 0 (as `wp.grad` of a clamp).
"""

from __future__ import annotations

import numpy as np

from ..controls import BETA_FLOOR
from .params import (
    EUMELANIN_SIGMA_A,
    PHEOMELANIN_SIGMA_A,
    HairParams,
    albedo_polynomial,
    sigma_a_from_albedo,
)

# Cycles' melanin absorption (bsdf_principled_hair_sigma_from_concentration) over d'Eon's, per pigment: the
# least-squares ratio of the RGB coefficients (they agree to 0.1% across channels).
_CYCLES_EUMELANIN = np.array([0.506, 0.841, 1.653])
_CYCLES_PHEOMELANIN = np.array([0.343, 0.733, 1.924])
CYCLES_MELANIN_UNITS = (
    float(_CYCLES_EUMELANIN @ EUMELANIN_SIGMA_A / (EUMELANIN_SIGMA_A @ EUMELANIN_SIGMA_A)),
    float(_CYCLES_PHEOMELANIN @ PHEOMELANIN_SIGMA_A / (PHEOMELANIN_SIGMA_A @ PHEOMELANIN_SIGMA_A)),
)
MELANIN_CLAMP = 1e-4  # Cycles' max(1 − melanin, 0.0001) before the log


def _rot(x, k):
    return (x << np.uint32(k)) | (x >> np.uint32(32 - k))


def hash_uint2(kx, ky):
    """lookup3's hash of two 32-bit words (Bob Jenkins, 2006, public domain; Cycles' util/hash.h `hash_uint2`)."""
    with np.errstate(over="ignore"):
        a = np.full(np.shape(kx), 0xDEADBEEF + (2 << 2) + 13, dtype=np.uint32)
        b = a.copy()
        c = a.copy()
        b += np.asarray(ky, dtype=np.uint32)
        a += np.asarray(kx, dtype=np.uint32)
        c ^= b
        c -= _rot(b, 14)
        a ^= c
        a -= _rot(c, 11)
        b ^= a
        b -= _rot(a, 25)
        c ^= b
        c -= _rot(b, 16)
        a ^= c
        a -= _rot(c, 4)
        b ^= a
        b -= _rot(a, 14)
        c ^= b
        c -= _rot(b, 24)
    return c


def strand_random(num_strands: int, seed: int = 0) -> np.ndarray:
    """(S,) float32 in [0, 1]: strand k's random value, hash_uint2(k, seed) / (2³² − 1) in float32 as Cycles."""
    n = hash_uint2(np.arange(num_strands, dtype=np.uint32), np.uint32(seed))
    return n.astype(np.float32) * np.float32(1.0 / np.float32(0xFFFFFFFF))


def spread_factor(u, spread):
    """1 + 2(u − ½)·spread: Cycles' per-strand factor, in [1 − spread, 1 + spread]."""
    return 1.0 + 2.0 * (np.asarray(u, dtype=np.float64) - 0.5) * spread


def strands_vary(params: HairParams) -> bool:
    """Whether the strands' looks differ from one to the next."""
    return params.color_spread > 0.0 or params.roughness_spread > 0.0


def tip_varies(params: HairParams) -> bool:
    """Whether the tip's absorption differs from the root's (tip_length alone changes nothing)."""
    return params.tip_absorption != 1.0


def has_variation(params: HairParams) -> bool:
    """Whether any strand's look differs from the material's, or the tip's from the root's."""
    return strands_vary(params) or tip_varies(params)


def tip_profile(t, tip_absorption, tip_length):
    """g(t) = 1 + (a − 1)·ramp(t), ramp = clamp((t − (1 − L)) / L, 0, 1): the factor on the absorption."""
    return 1.0 + (tip_absorption - 1.0) * tip_ramp(t, tip_length)


def tip_ramp(t, tip_length):
    return np.clip((np.asarray(t, dtype=np.float64) - (1.0 - tip_length)) / tip_length, 0.0, 1.0)


def melanin_factor(total, f):
    """(k, ∂k/∂total, ∂k/∂f): the factor on a melanin look's concentrations that Cycles' Random Color gives a
    strand with factor f, total = M the look's melanin in Cycles' units (k = f where M = 0, the limit)."""
    total = np.asarray(total, dtype=np.float64)
    f = np.asarray(f, dtype=np.float64)
    m = -np.expm1(-total)  # Cycles' perceptual Melanin input
    inside = 1.0 - f * m
    live = inside > MELANIN_CLAMP
    strand_total = -np.log(np.maximum(inside, MELANIN_CLAMP))
    d_strand_d_m = np.where(live, f / np.maximum(inside, MELANIN_CLAMP), 0.0)
    d_strand_d_f = np.where(live, m / np.maximum(inside, MELANIN_CLAMP), 0.0)
    dm = np.exp(-total)
    small = total < 1e-12
    safe = np.where(small, 1.0, total)
    k = np.where(small, f, strand_total / safe)
    dk_dtotal = np.where(small, 0.0, (d_strand_d_m * dm - k) / safe)
    dk_df = np.where(small, 1.0, d_strand_d_f / safe)
    return k, dk_dtotal, dk_df


class StrandLooks:
    """Per strand (arrays of S): the coefficients' inputs and their derivatives in the look's controls θ.

    sigma_a (S, 3), beta_m, beta_n (S,): the strand's values (β before the floor);
    d_sigma_d_colour (S, 3, 3): ∂σ_a,c/∂θ_colour; d_sigma_d_beta_n (S, 3); d_beta_m_d_beta_m, d_beta_n_d_beta_n
    (S,): the strand's β in the look's (f_r, or 0 where clamped); d_sigma_d_color_spread,
    d_sigma_d_roughness_spread (S, 3); d_beta_m_d_spread, d_beta_n_d_spread (S,).
    """

    def __init__(self, **arrays):
        self.__dict__.update(arrays)


def _strand_beta(beta, factor, w):
    """(β·f clamped to [0, 1], ∂/∂β, ∂/∂spread): 0 where the clamp holds it."""
    raw = beta * factor
    value = np.clip(raw, 0.0, 1.0)
    live = (raw > 0.0) & (raw < 1.0)
    return value, np.where(live, factor, 0.0), np.where(live, beta * w, 0.0)


def _slope(mapping, x):
    """d mapping/dx by the complex step, elementwise (mapping is plain arithmetic: params.py's polynomials)."""
    step = 1e-30
    return np.imag(mapping(np.asarray(x, dtype=np.float64) + 1j * step)) / step


def strand_looks(params: HairParams, u) -> StrandLooks:
    """Each strand's σ_a, β_m, β_n for random values u (S,), with their derivatives (float64)."""
    u = np.asarray(u, dtype=np.float64)
    w = 2.0 * (u - 0.5)  # ∂f/∂spread
    f_rough = spread_factor(u, params.roughness_spread)
    f_colour = spread_factor(u, params.color_spread)
    beta_m, dbm, dbm_spread = _strand_beta(params.beta_m, f_rough, w)
    beta_n, dbn, dbn_spread = _strand_beta(params.beta_n, f_rough, w)
    strands = len(u)
    d_colour = np.zeros((strands, 3, 3))
    d_beta_n = np.zeros((strands, 3))
    d_color_spread = np.zeros((strands, 3))
    mode = params.colour_input
    if mode == "albedo":
        albedo = np.asarray(params.albedo, dtype=np.float64)
        coefficients = params.albedo_inversion
        # P(β_n) at the strand's β_n, floored as the lobes use it (derivative 0 at the floor).
        floored = np.maximum(beta_n, BETA_FLOOR)
        denominator = albedo_polynomial(floored, coefficients)
        base = sigma_a_from_albedo(albedo[None, :], floored[:, None], coefficients)  # (S, 3)
        d_base_d_albedo = 2.0 * np.log(albedo)[None, :] / (denominator[:, None] ** 2 * albedo[None, :])
        slope = np.where(beta_n > BETA_FLOOR, _slope(lambda b: albedo_polynomial(b, coefficients), floored), 0.0)
        d_base_d_beta_n = -2.0 * base * (slope / denominator)[:, None]  # per unit of the strand's β_n
        sigma = f_colour[:, None] * base
        for c in range(3):
            d_colour[:, c, c] = f_colour * d_base_d_albedo[:, c]
        d_beta_n = f_colour[:, None] * d_base_d_beta_n * dbn[:, None]
        d_rough = f_colour[:, None] * d_base_d_beta_n * dbn_spread[:, None]
        d_color_spread = w[:, None] * base
    elif mode == "sigma_a":
        base = np.asarray(params.sigma_a, dtype=np.float64)[None, :]
        sigma = f_colour[:, None] * base
        for c in range(3):
            d_colour[:, c, c] = f_colour
        d_rough = np.zeros((strands, 3))
        d_color_spread = w[:, None] * base
    else:
        eu, pheo = params.eumelanin, params.pheomelanin
        units_eu, units_pheo = CYCLES_MELANIN_UNITS
        total = eu / units_eu + pheo / units_pheo
        k, dk_dtotal, dk_df = melanin_factor(total, f_colour)
        base = eu * EUMELANIN_SIGMA_A + pheo * PHEOMELANIN_SIGMA_A  # (3,)
        sigma = k[:, None] * base[None, :]
        # σ = k(M(eu, pheo)) (eu E + pheo P): columns 0 (eumelanin) and 1 (pheomelanin).
        d_colour[:, :, 0] = k[:, None] * EUMELANIN_SIGMA_A + (dk_dtotal / units_eu)[:, None] * base
        d_colour[:, :, 1] = k[:, None] * PHEOMELANIN_SIGMA_A + (dk_dtotal / units_pheo)[:, None] * base
        d_rough = np.zeros((strands, 3))
        d_color_spread = (dk_df * w)[:, None] * base[None, :]
    return StrandLooks(
        sigma_a=sigma,
        beta_m=beta_m,
        beta_n=beta_n,
        d_sigma_d_colour=d_colour,
        d_sigma_d_beta_n=d_beta_n,
        d_beta_m_d_beta_m=dbm,
        d_beta_n_d_beta_n=dbn,
        d_sigma_d_color_spread=d_color_spread,
        d_sigma_d_roughness_spread=d_rough,
        d_beta_m_d_spread=dbm_spread,
        d_beta_n_d_spread=dbn_spread,
    )
