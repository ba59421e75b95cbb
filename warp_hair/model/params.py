"""The artist controls of the Chiang et al. hair/fur model (HairParams) and their mappings to model coefficients.

The controls themselves (names, ranges, defaults, θ columns) are the table in `warp_hair.controls`.

Everything here is plain float64 NumPy: it runs once per material, not per sample. The Warp kernels read
the derived coefficients (σ_a, per-lobe longitudinal variance, logistic scale, tilt) from
`warp_hair.model.hair_bsdf.HairCoefficients`.
"""

from __future__ import annotations

import inspect
import math
import warnings
from dataclasses import dataclass

import numpy as np

from .. import validate
from ..controls import (
    BETA_FLOOR,
    COLOUR_CONTROL_NAMES,
    COLOUR_CONTROLS,
    CONTROL_NAMES,
    CONTROLS,
    VARIATION_CONTROLS,
    controls_of,
    describe,
)

# d'Eon et al. 2011 absorption of the two melanins per unit fiber radius (docs/MODEL.md, "From artist controls").
EUMELANIN_SIGMA_A = np.array([0.419, 0.697, 1.37])
PHEOMELANIN_SIGMA_A = np.array([0.187, 0.4, 1.05])


# The [hair] key of the albedo inversion's table (not a control: see HairParams).
ALBEDO_INVERSION_KEY = "albedo_inversion"


def effective_beta(beta):
    """The roughness the lobes use: β below BETA_FLOOR behaves as BETA_FLOOR."""
    return np.maximum(beta, BETA_FLOOR)


# The talk's roughness mappings (docs/MODEL.md, "From artist controls"), as plain arithmetic so that they also take
# complex steps (jacobian.py's derivatives). The exporters write them for renderers whose own floor differs
# (export/materialx.py, export/cycles.py): the polynomials are here once, without the floor.


def longitudinal_polynomial(beta):
    """0.726 β + 0.812 β² + 3.7 β²⁰, whose square is the longitudinal variance v(β) (no floor)."""
    return 0.726 * beta + 0.812 * beta**2 + 3.7 * beta**20


def logistic_polynomial(beta):
    """0.265 β + 1.194 β² + 5.372 β²², the logistic scale s(β) without the factor sqrt(π/8) (no floor)."""
    return 0.265 * beta + 1.194 * beta**2 + 5.372 * beta**22


def longitudinal_variance(beta_m):
    """v(β_m) = (0.726 β + 0.812 β² + 3.7 β²⁰)², the variance of the R... TRT base lobe (docs/MODEL.md)."""
    return longitudinal_polynomial(effective_beta(beta_m)) ** 2


def lobe_variances(beta_m, r_roughness_scale=1.0):
    """Per-lobe longitudinal variances [R, TT, TRT, residual]: v·scale, v/4, 4v, 4v."""
    v = longitudinal_variance(beta_m)
    return np.array([v * r_roughness_scale, 0.25 * v, 4.0 * v, 4.0 * v])


def logistic_scale(beta_n):
    """s(β_n) = sqrt(π/8)(0.265 β + 1.194 β² + 5.372 β²²); the talk omits sqrt(π/8), all renderers keep it."""
    return math.sqrt(math.pi / 8.0) * logistic_polynomial(effective_beta(beta_n))


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
    latents) and complex steps (model.jacobian's derivatives)."""
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
    values = np.atleast_1d(np.asarray(coefficients, dtype=object))
    count = ALBEDO_INVERSION_DEGREE + 1
    if values.shape != (count,):  # a nested list is not flattened
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
    """An RGB triple from a number (grey) or a flat sequence of one or three numbers."""
    values = np.asarray(value, dtype=object)
    if values.ndim > 1 or values.size not in (1, 3):
        raise ValueError(f"{name} must be one number or three (RGB), in a flat list, got {value!r}")
    values = np.atleast_1d(values)
    if values.size == 1:
        values = np.repeat(values, 3)
    return tuple(_real(f"{name}[{c}]", v) for c, v in zip("rgb", values))


def _checked(name, value):
    """A control's value as HairParams keeps it (a float, or a tuple of three), checked against the table; below
    a control's floor, a warning that the floor is rendered."""
    control = CONTROLS[name]
    if control.size == 3:
        value = _rgb(name, value)
        for c, v in zip("rgb", value):
            control.check(v, f"{name}[{c}]")
        return value
    value = _real(name, value)
    control.check(value)
    if control.floor is not None and value < control.floor:
        warnings.warn(
            f"{name} = {value} is below {control.floor}, the narrowest lobe the model can sample; "
            f"it is rendered as {control.floor}",
            stacklevel=3,  # HairParams' caller
        )
    return value


def _given_colour(controls: dict) -> str:
    """The one colour input among the given controls, or a ValueError listing what was given."""
    given = [
        colour_input
        for colour_input, names in COLOUR_CONTROLS.items()
        if any(controls.get(name) is not None for name in names)
    ]
    if len(given) != 1:
        found = ", ".join("/".join(COLOUR_CONTROLS[g]) for g in given) if given else "none"
        *first, last = ("/".join(names) for names in COLOUR_CONTROLS.values())
        allowed = f"{', '.join(first)}, or {last}"
        raise ValueError(f"HairParams needs exactly one colour input: {allowed} (got {found})")
    return given[0]


def _fields() -> dict:
    """HairParams' fields: one per control of the table, named as the control, then the albedo inversion."""
    fields = {name: "tuple | None" if control.size == 3 else "float | None" for name, control in CONTROLS.items()}
    fields[ALBEDO_INVERSION_KEY] = "tuple"
    return fields


@dataclass(frozen=True, init=False)
class HairParams:
    """The artist controls of the Chiang et al. 2015 hair/fur model (the table: `warp_hair.controls`).

    Colour: give exactly one of
      - ``albedo``: RGB multiple-scattering albedo (a single number means grey); σ_a follows from the talk's
        albedo inversion, which depends on β_n;
      - ``sigma_a``: RGB absorption coefficient per unit fiber radius (a single number means grey);
      - ``eumelanin`` and/or ``pheomelanin``: pigment concentrations (the one not given is 0).
    Roughnesses below BETA_FLOOR (0.01) are rendered as the floor (with a warning), because a zero-width lobe
    cannot be sampled. Every control is a number: a bool or a string is an error. The controls, their ranges
    and defaults:

    {table}

    Each control is an attribute of the same name, holding the value as given (RGB as a tuple of three; the
    colour inputs not given are None). The absorption the model uses, whatever the colour input, is
    ``absorption`` (``sigma_a`` is the input).

    ``albedo_inversion`` is not a control but the calibration behind the albedo input: the coefficients
    p_0 ... p_5 of P(β_n) in σ_a = (ln c / P(β_n))², by default the talk's (TALK_ALBEDO_INVERSION); P must be
    positive over [0.01, 1]. `warp-hair calibrate` fits them for a given assembly and lighting.
    """

    __annotations__ = _fields()

    def __init__(self, **controls):
        unknown = sorted(set(controls) - set(CONTROL_NAMES) - {ALBEDO_INVERSION_KEY})
        if unknown:
            raise TypeError(f"HairParams got unknown control(s) {unknown}; allowed: {list(CONTROL_NAMES)}")
        colour_input = _given_colour(controls)
        for name, control in CONTROLS.items():
            if control.colour_input is None:
                value = _checked(name, controls.get(name, control.default))
            elif control.colour_input == colour_input:
                value = controls.get(name)
                value = _checked(name, control.default if value is None else value)  # a melanin not given is 0
            else:
                value = None
            object.__setattr__(self, name, value)
        inversion = controls.get(ALBEDO_INVERSION_KEY, TALK_ALBEDO_INVERSION)
        object.__setattr__(self, ALBEDO_INVERSION_KEY, check_albedo_inversion(inversion))

    @property
    def colour_input(self) -> str:
        """Which colour control the user gave: "albedo", "sigma_a" or "melanin"."""
        return _given_colour({name: getattr(self, name) for name in COLOUR_CONTROL_NAMES})

    @property
    def absorption(self) -> np.ndarray:
        """σ_a, the absorption coefficient (RGB, per unit fiber radius) the model uses, whatever the colour input:
        derived from the albedo or the melanins, or the ``sigma_a`` input itself."""
        if self.albedo is not None:
            return sigma_a_from_albedo(self.albedo, self.beta_n, self.albedo_inversion)
        if self.sigma_a is not None:
            return np.array(self.sigma_a, dtype=np.float64)
        return sigma_a_from_melanin(self.eumelanin, self.pheomelanin)

    @property
    def lobe_variances(self) -> np.ndarray:
        """Longitudinal variances [R, TT, TRT, residual]."""
        return lobe_variances(self.beta_m, self.r_roughness_scale)

    @property
    def logistic_scale(self) -> float:
        return logistic_scale(self.beta_n)

    def to_dict(self) -> dict:
        """The controls as given, as a flat dict of named values (colour under its own input's name, RGB as lists
        of three), in `controls.controls_of` order; the albedo inversion is not a control and is not in it (see
        `to_table`)."""
        d = {}
        for name in controls_of(self.colour_input):
            value = getattr(self, name)
            d[name] = list(value) if CONTROLS[name].size == 3 else value
        return d

    def to_table(self) -> dict:
        """A scene file's [hair] table: the controls (the variation's only where the look varies: a uniform
        look's table is as it was before they existed), plus [hair.albedo_inversion] when it is not the talk's."""
        d = {
            name: value
            for name, value in self.to_dict().items()
            if name not in VARIATION_CONTROLS or value != CONTROLS[name].default
        }
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
                f"unknown key(s) {unknown} in {where}; allowed: {[*list(CONTROL_NAMES), ALBEDO_INVERSION_KEY]}"
            )
        controls = dict(controls)
        if ALBEDO_INVERSION_KEY in controls:
            controls[ALBEDO_INVERSION_KEY] = _inversion_table(controls[ALBEDO_INVERSION_KEY], where)
        return cls(**controls)

    def replace(self, **changes) -> HairParams:
        """A copy with some controls changed (the albedo inversion kept unless given); changing the colour input
        replaces the old one."""
        d = self.to_dict()
        if set(COLOUR_CONTROL_NAMES) & set(changes):
            for key in COLOUR_CONTROL_NAMES:
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


HairParams.__doc__ = HairParams.__doc__.replace("{table}", describe().replace("\n", "\n    "))
# help() and editors show the keywords the table gives (the constructor takes them as **controls).
HairParams.__signature__ = inspect.Signature(
    [
        inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=None if c.colour_input else c.default)
        for name, c in CONTROLS.items()
    ]
    + [inspect.Parameter(ALBEDO_INVERSION_KEY, inspect.Parameter.KEYWORD_ONLY, default=TALK_ALBEDO_INVERSION)]
)
