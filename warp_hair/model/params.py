"""The six artist controls of the Chiang et al. hair/fur model and their mappings to model coefficients.

Everything here is plain float64 NumPy: it runs once per material, not per sample. The Warp kernels read
the derived coefficients (σ_a, per-lobe longitudinal variance, logistic scale, tilt) from
`warp_hair.model.hair_bsdf.HairCoefficients`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .. import validate

# Below this roughness the lobes are narrower than float32 angles can resolve, and at 0 the mappings give
# v = s = 0 (a delta lobe no path tracer can sample). pbrt, Mitsuba and Cycles clamp the same way.
BETA_FLOOR = 0.01

# d'Eon et al. 2011 absorption of the two melanins per unit fiber radius (MODEL.md, "From artist controls").
EUMELANIN_SIGMA_A = np.array([0.419, 0.697, 1.37])
PHEOMELANIN_SIGMA_A = np.array([0.187, 0.4, 1.05])

ALPHA_RANGE_DEG = (-30.0, 30.0)
# η: above 1 (a fiber that refracts); 10 is beyond every dielectric in visible light (diamond 2.4, silicon ~4).
ETA_MAX = 10.0
# The R lobe's variance factor: 1e-6 to 1e6 spans any species by far, and the lobes are tested finite there.
R_ROUGHNESS_SCALE_RANGE = (1e-6, 1e6)
# Absorption (σ_a, or a melanin concentration) beyond this is black to float32 precision, and σ_a times a path
# length must stay finite.
ABSORPTION_MAX = 1e30

# The [hair] key of the albedo inversion's table (not a control: see HairParams).
ALBEDO_INVERSION_KEY = "albedo_inversion"

CONTROL_NAMES = (
    "albedo",
    "sigma_a",
    "eumelanin",
    "pheomelanin",
    "beta_m",
    "beta_n",
    "alpha",
    "eta",
    "r_roughness_scale",
)


def effective_beta(beta):
    """The roughness the lobes use: β below BETA_FLOOR behaves as BETA_FLOOR."""
    return np.maximum(beta, BETA_FLOOR)


def longitudinal_variance(beta_m):
    """v(β_m) = (0.726 β + 0.812 β² + 3.7 β²⁰)², the variance of the R... TRT base lobe (MODEL.md)."""
    b = effective_beta(beta_m)
    return (0.726 * b + 0.812 * b**2 + 3.7 * b**20) ** 2


def lobe_variances(beta_m, r_roughness_scale=1.0):
    """Per-lobe longitudinal variances [R, TT, TRT, residual]: v·scale, v/4, 4v, 4v."""
    v = longitudinal_variance(beta_m)
    return np.array([v * r_roughness_scale, 0.25 * v, 4.0 * v, 4.0 * v])


def logistic_scale(beta_n):
    """s(β_n) = sqrt(π/8)(0.265 β + 1.194 β² + 5.372 β²²); the talk omits sqrt(π/8), all renderers keep it."""
    b = effective_beta(beta_n)
    return math.sqrt(math.pi / 8.0) * (0.265 * b + 1.194 * b**2 + 5.372 * b**22)


# The albedo inversion σ_a = (ln c / P(β_n))², P(b) = Σ_k p_k b^k of degree 5: the coefficients p_0 ... p_5 that
# Chiang et al. fitted to brute-force renders of a dense block of fibers (talk, "Controllability").
# `warp-hair calibrate` refits them for a user's own assembly and lighting ([hair.albedo_inversion] in a scene).
TALK_ALBEDO_INVERSION = (5.969, -0.215, 2.532, -10.73, 5.574, 0.245)
ALBEDO_INVERSION_DEGREE = len(TALK_ALBEDO_INVERSION) - 1
# P must stay positive over the β_n the model renders, [BETA_FLOOR, 1]: at a root σ_a blows up, past one it
# would fall again as albedo rises.
ALBEDO_INVERSION_RANGE = (BETA_FLOOR, 1.0)


def albedo_denominator(beta_n, coefficients):
    """P(β_n) of the albedo inversion with the given coefficients (p_0 ... p_5), β_n floored as the lobes use it."""
    return albedo_polynomial(effective_beta(beta_n), coefficients)


def albedo_polynomial(b, coefficients):
    """albedo_denominator without the floor: plain arithmetic (Horner), so it also takes torch tensors (the fit's
    latents) and complex steps (bsdf_jacobian's derivatives)."""
    value = 0.0
    for p in reversed(coefficients):
        value = value * b + float(p)
    return value


def sigma_a_from_albedo(albedo, beta_n, coefficients):
    """σ_a = (ln c / P(β_n))²: the absorption that gives multiple-scattering albedo c (talk, Controllability)."""
    return (np.log(np.asarray(albedo, dtype=np.float64)) / albedo_denominator(beta_n, coefficients)) ** 2


def check_albedo_inversion(coefficients, name="albedo_inversion"):
    """The coefficients p_0 ... p_5 as a tuple of floats, or a ValueError naming `name` if there are not six
    finite numbers or if P(β_n) is not positive over all of [0.01, 1]."""
    values = np.atleast_1d(np.asarray(coefficients, dtype=object)).ravel()
    count = ALBEDO_INVERSION_DEGREE + 1
    if values.size != count:
        raise ValueError(
            f"{name} must be {count} numbers (p_0 ... p_{ALBEDO_INVERSION_DEGREE} of P(β_n) = Σ p_k β_n^k), "
            f"got {coefficients!r}"
        )
    values = tuple(_real(f"{name}[{k}]", v) for k, v in enumerate(values))
    lo, hi = ALBEDO_INVERSION_RANGE
    polynomial = np.polynomial.Polynomial(values)
    # P > 0 on [lo, hi] iff it is positive at lo and has no real root in (lo, hi].
    roots = [r.real for r in polynomial.roots() if abs(r.imag) <= 1e-9 * max(1.0, abs(r)) and lo <= r.real <= hi]
    if polynomial(lo) <= 0 or roots:
        if polynomial(lo) <= 0:
            found = f"P(β_n) = {polynomial(lo):.3g} at β_n = {lo}"
        else:
            found = f"P(β_n) = 0 at β_n = {min(roots):.3g}"
        raise ValueError(
            f"{name} = {list(values)} gives {found}: the polynomial must be positive over all of [{lo}, {hi}], "
            "or σ_a = (ln c / P(β_n))² blows up"
        )
    return values


def sigma_a_from_melanin(eumelanin, pheomelanin):
    return eumelanin * EUMELANIN_SIGMA_A + pheomelanin * PHEOMELANIN_SIGMA_A


def _real(name, value):
    return validate.real(name, value)


def _rgb(name, value):
    """An RGB triple from a number (grey) or a sequence of three numbers."""
    values = np.atleast_1d(np.asarray(value, dtype=object)).ravel()
    if values.size == 1:
        values = np.repeat(values, 3)
    if values.size != 3:
        raise ValueError(f"{name} must be one number or three (RGB), got {value!r}")
    return tuple(_real(f"{name}[{c}]", v) for c, v in zip("rgb", values))


def _check_range(name, value, lo, hi, lo_open=False, hi_open=False):
    below = value <= lo if lo_open else value < lo
    above = value >= hi if hi_open else value > hi
    if below or above:
        interval = f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"
        raise ValueError(f"{name} = {value} is outside the allowed range {interval}")


@dataclass(frozen=True)
class HairParams:
    """The artist controls of the Chiang et al. 2015 hair/fur model.

    Colour: give exactly one of
      - ``albedo``: RGB multiple-scattering albedo, each channel in (0, 1] (a single number means grey);
        σ_a follows from the talk's albedo inversion, which depends on β_n;
      - ``sigma_a``: RGB absorption coefficient per unit fiber radius, each ≥ 0;
      - ``eumelanin`` and/or ``pheomelanin``: pigment concentrations ≥ 0 (blonde ≈ 0.3, brown ≈ 1.3, black ≈ 8).
    Roughness ``beta_m`` (longitudinal) and ``beta_n`` (azimuthal) in [0, 1]; values below 0.01 are rendered
    as 0.01 (with a warning), because a zero-width lobe cannot be sampled. ``alpha`` is the cuticle tilt in
    degrees, in [-30, 30], ``eta`` the index of refraction, in (1, 10], ``r_roughness_scale`` the species
    control, in [1e-6, 1e6]: a factor on the primary reflection (R) lobe's longitudinal variance only. σ_a and
    the melanins are at most 1e30. Every control is a number: a bool or a string is an error.

    ``albedo_inversion`` is not a control but the calibration behind the albedo input: the coefficients
    p_0 ... p_5 of P(β_n) in σ_a = (ln c / P(β_n))², by default the talk's (TALK_ALBEDO_INVERSION); P must be
    positive over [0.01, 1]. `warp-hair calibrate` fits them for a given assembly and lighting.
    """

    albedo: tuple | None = None
    sigma_a_input: tuple | None = field(default=None, repr=False)
    eumelanin: float | None = None
    pheomelanin: float | None = None
    beta_m: float = 0.3
    beta_n: float = 0.3
    alpha: float = 2.0
    eta: float = 1.55
    r_roughness_scale: float = 1.0
    albedo_inversion: tuple = TALK_ALBEDO_INVERSION

    def __init__(
        self,
        *,
        albedo=None,
        sigma_a=None,
        eumelanin=None,
        pheomelanin=None,
        beta_m=0.3,
        beta_n=0.3,
        alpha=2.0,
        eta=1.55,
        r_roughness_scale=1.0,
        albedo_inversion=TALK_ALBEDO_INVERSION,
    ):
        given = [name for name, v in (("albedo", albedo), ("sigma_a", sigma_a)) if v is not None]
        if eumelanin is not None or pheomelanin is not None:
            given.append("eumelanin/pheomelanin")
        if len(given) != 1:
            found = ", ".join(given) if given else "none"
            raise ValueError(
                "HairParams needs exactly one colour input: albedo, sigma_a, or eumelanin/pheomelanin "
                f"(got {found})"
            )
        set_ = object.__setattr__
        if albedo is not None:
            albedo = _rgb("albedo", albedo)
            for c, a in zip("rgb", albedo):
                _check_range(f"albedo[{c}]", a, 0.0, 1.0, lo_open=True)
        if sigma_a is not None:
            sigma_a = _rgb("sigma_a", sigma_a)
            for c, s in zip("rgb", sigma_a):
                _check_range(f"sigma_a[{c}]", s, 0.0, ABSORPTION_MAX)
        if eumelanin is not None or pheomelanin is not None:
            eumelanin = _real("eumelanin", 0.0 if eumelanin is None else eumelanin)
            pheomelanin = _real("pheomelanin", 0.0 if pheomelanin is None else pheomelanin)
            _check_range("eumelanin", eumelanin, 0.0, ABSORPTION_MAX)
            _check_range("pheomelanin", pheomelanin, 0.0, ABSORPTION_MAX)
        beta_m, beta_n = _real("beta_m", beta_m), _real("beta_n", beta_n)
        for name, b in (("beta_m", beta_m), ("beta_n", beta_n)):
            _check_range(name, b, 0.0, 1.0)
            if b < BETA_FLOOR:
                warnings.warn(
                    f"{name} = {b} is below {BETA_FLOOR}, the narrowest lobe the model can sample; "
                    f"it is rendered as {BETA_FLOOR}",
                    stacklevel=2,
                )
        alpha = _real("alpha", alpha)
        _check_range("alpha", alpha, *ALPHA_RANGE_DEG)
        eta = _real("eta", eta)
        _check_range("eta", eta, 1.0, ETA_MAX, lo_open=True)
        r_roughness_scale = _real("r_roughness_scale", r_roughness_scale)
        _check_range("r_roughness_scale", r_roughness_scale, *R_ROUGHNESS_SCALE_RANGE)

        set_(self, "albedo", albedo)
        set_(self, "sigma_a_input", sigma_a)
        set_(self, "eumelanin", eumelanin)
        set_(self, "pheomelanin", pheomelanin)
        set_(self, "beta_m", beta_m)
        set_(self, "beta_n", beta_n)
        set_(self, "alpha", alpha)
        set_(self, "eta", eta)
        set_(self, "r_roughness_scale", r_roughness_scale)
        set_(self, "albedo_inversion", check_albedo_inversion(albedo_inversion))

    @property
    def colour_input(self) -> str:
        """Which colour control the user gave: "albedo", "sigma_a" or "melanin"."""
        if self.albedo is not None:
            return "albedo"
        if self.sigma_a_input is not None:
            return "sigma_a"
        return "melanin"

    @property
    def sigma_a(self) -> np.ndarray:
        """The absorption coefficient (RGB, per unit fiber radius) the model uses, whatever the colour input."""
        if self.albedo is not None:
            return sigma_a_from_albedo(self.albedo, self.beta_n, self.albedo_inversion)
        if self.sigma_a_input is not None:
            return np.array(self.sigma_a_input, dtype=np.float64)
        return sigma_a_from_melanin(self.eumelanin, self.pheomelanin)

    @property
    def lobe_variances(self) -> np.ndarray:
        """Longitudinal variances [R, TT, TRT, residual]."""
        return lobe_variances(self.beta_m, self.r_roughness_scale)

    @property
    def logistic_scale(self) -> float:
        return logistic_scale(self.beta_n)

    def to_dict(self) -> dict:
        """The controls as given, as a flat dict of named values (colour under its own input's name); the
        albedo inversion is not a control and is not in it (see `to_table`)."""
        d = {}
        if self.colour_input == "albedo":
            d["albedo"] = list(self.albedo)
        elif self.colour_input == "sigma_a":
            d["sigma_a"] = list(self.sigma_a_input)
        else:
            d["eumelanin"], d["pheomelanin"] = self.eumelanin, self.pheomelanin
        d.update(
            beta_m=self.beta_m,
            beta_n=self.beta_n,
            alpha=self.alpha,
            eta=self.eta,
            r_roughness_scale=self.r_roughness_scale,
        )
        return d

    def to_table(self) -> dict:
        """A scene file's [hair] table: the controls, plus [hair.albedo_inversion] when it is not the talk's."""
        d = self.to_dict()
        if self.albedo_inversion != TALK_ALBEDO_INVERSION:
            d[ALBEDO_INVERSION_KEY] = {"coefficients": list(self.albedo_inversion)}
        return d

    @classmethod
    def from_dict(cls, controls: dict, where: str = "hair controls") -> HairParams:
        """Build from a flat dict (a scene file's [hair] table, `to_table`'s output); unknown keys are errors
        naming the key. An ``albedo_inversion`` entry is a table holding ``coefficients``."""
        unknown = sorted(set(controls) - set(CONTROL_NAMES) - {ALBEDO_INVERSION_KEY})
        if unknown:
            raise ValueError(
                f"unknown key(s) {unknown} in {where}; allowed: {list(CONTROL_NAMES) + [ALBEDO_INVERSION_KEY]}"
            )
        controls = dict(controls)
        if ALBEDO_INVERSION_KEY in controls:
            controls[ALBEDO_INVERSION_KEY] = _inversion_table(controls[ALBEDO_INVERSION_KEY], where)
        return cls(**controls)

    def replace(self, **changes) -> HairParams:
        """A copy with some controls changed (the albedo inversion kept unless given); changing the colour input
        replaces the old one."""
        d = self.to_dict()
        if {"albedo", "sigma_a", "eumelanin", "pheomelanin"} & set(changes):
            for key in ("albedo", "sigma_a", "eumelanin", "pheomelanin"):
                d.pop(key, None)
        d[ALBEDO_INVERSION_KEY] = self.albedo_inversion
        d.update(changes)
        return HairParams(**d)


def _inversion_table(table, where) -> tuple:
    """The coefficients of an [hair.albedo_inversion] table, checked, with errors naming the table's key."""
    if not isinstance(table, dict):
        raise ValueError(f"{where}: {ALBEDO_INVERSION_KEY} must be a table with a coefficients key, got {table!r}")
    if set(table) != {"coefficients"}:
        raise ValueError(
            f"{where}: {ALBEDO_INVERSION_KEY} takes one key, coefficients (p_0 ... p_5); got keys {sorted(table)}"
        )
    try:
        return check_albedo_inversion(table["coefficients"], f"{ALBEDO_INVERSION_KEY}.coefficients")
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
