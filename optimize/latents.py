"""The controls a fit can move, and the unconstrained latents the optimiser moves instead.

Adam steps in latent space; each control is a fixed smooth map of its latent onto the open interval the
control may take, so no step can leave the valid range and nothing is clipped:

    bounded (lo, hi)      x = lo + (hi − lo) · sigmoid(z)     β_m, β_n, α, η
    bounded below (lo, ∞) x = lo + exp(z)                     σ_a, melanins, r_roughness_scale, exposure
    albedo, in (0, 1)     a = exp(−e^(z/2) · P(β_n))          z = log σ_a, the absorption it stands for

The albedo's latent is the log of the absorption σ_a = (ln a / P(β_n))² the renderer derives from it (talk,
"Controllability"; P with the target's own inversion coefficients, HairParams.albedo_inversion). Albedo and β_n are
coupled through that inversion: at fixed albedo a change of β_n changes
σ_a too, so in (albedo, β_n) the loss has a long diagonal valley that plain Adam crawls along. In (log σ_a, β_n)
each latent has its own effect on the images (absorption; azimuthal spread), and the fit converges in a fraction
of the iterations. The result is still reported, and its uncertainty estimated, as albedo.

The roughnesses live in (BETA_FLOOR, 1), not [0, 1]: below the floor the renderer clamps β, so the loss would be
flat there and the fit stuck. "exposure" is not a hair control: it is a gain on every rendered image, for targets
whose light level is not known exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from warp_hair.controls import COLOUR_CONTROL_NAMES, COLOUR_CONTROLS, CONTROLS
from warp_hair.model.params import albedo_polynomial

EXPOSURE = "exposure"
DEFAULT_FIT = ("albedo", "beta_m", "beta_n")


def hair_and_gain(values: dict) -> tuple:
    """({control: value} of the hair among fitted `values`, the gain on every render: exposure, 1 unfitted)."""
    return {name: v for name, v in values.items() if name != EXPOSURE}, values.get(EXPOSURE, 1.0)


@dataclass(frozen=True)
class ControlSpec:
    """A fittable control: its size (3 for RGB), its open interval, and the neutral starting guess."""

    name: str
    size: int
    lo: float
    hi: float  # math.inf for controls bounded below only
    neutral: float

    @property
    def interval(self) -> str:
        return f"({self.lo:g}, {self.hi:g})"

    def to_latent(self, value: torch.Tensor, beta_n, inversion=None) -> torch.Tensor:
        """The latent of a value; `beta_n` and `inversion` (the coefficients of P) are used by albedo only."""
        if self.name == "albedo":
            _need_inversion(inversion)
            return 2.0 * torch.log(-torch.log(value) / albedo_polynomial(beta_n, inversion))
        if math.isinf(self.hi):
            return torch.log(value - self.lo)
        return torch.logit((value - self.lo) / (self.hi - self.lo))

    def from_latent(self, latent: torch.Tensor, beta_n, inversion=None) -> torch.Tensor:
        """The control's value; `beta_n` (≥ BETA_FLOOR, a tensor when it is fitted too) and `inversion` (the
        coefficients of P) are used by albedo only."""
        if self.name == "albedo":
            _need_inversion(inversion)
            return torch.exp(-torch.exp(0.5 * latent) * albedo_polynomial(beta_n, inversion))
        if math.isinf(self.hi):
            return self.lo + torch.exp(latent)
        return self.lo + (self.hi - self.lo) * torch.sigmoid(latent)

    def check_start(self, values: list[float], where: str) -> None:
        """A start must lie strictly inside the interval: the latent of a bound is infinite."""
        for k, v in enumerate(values):
            label = self.name if self.size == 1 else f"{self.name}[{k}]"
            if not (math.isfinite(v) and self.lo < v < self.hi):
                raise ValueError(
                    f"{where}: {label} = {v} cannot start a fit: it must lie strictly inside {self.interval}"
                )


def _need_inversion(inversion) -> None:
    if inversion is None:
        raise ValueError(
            "the albedo's latent needs the target's albedo inversion coefficients (HairParams.albedo_inversion)"
        )


def _spec(name: str) -> ControlSpec:
    """A hair control's spec, from the table: its size, its open interval (the control's range, from its floor
    if it has one and up to `fit_hi` if given: every latent's map reaches a bound only at infinity) and its start
    (`fit_start`, else the default)."""
    control = CONTROLS[name]
    return ControlSpec(
        name,
        control.size,
        control.fit_lo,
        control.hi if control.fit_hi is None else control.fit_hi,
        control.default if control.fit_start is None else control.fit_start,
    )


SPECS = {name: _spec(name) for name in CONTROLS} | {EXPOSURE: ControlSpec(EXPOSURE, 1, 0.0, math.inf, 1.0)}


def parse_control_names(names, colour_input: str) -> tuple:
    """The controls to fit, validated against the scene's colour input; `names` a list or "a,b,c"."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = list(names)
    if not names:
        raise ValueError("no controls to fit: give at least one, e.g. albedo,beta_m,beta_n")
    colour = COLOUR_CONTROLS[colour_input]
    for name in names:
        if name not in SPECS:
            raise ValueError(f"unknown control {name!r} to fit; allowed: {list(SPECS)}")
        if name in COLOUR_CONTROL_NAMES and name not in colour:
            raise ValueError(
                f"cannot fit {name!r}: the target's scenes give the hair colour as {colour_input!r}, so the colour "
                f"control is {' and '.join(repr(c) for c in colour)}"
            )
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"control(s) {duplicates} listed twice to fit")
    return tuple(names)


def flat_values(values: dict) -> np.ndarray:
    """The components of `values` ({name: float, or list of 3}) as one float64 vector, in its order: `by_control`'s
    inverse."""
    return np.concatenate([np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in values.values()])


def component_bounds(names) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): each control component's open interval, in `names` order."""
    lo = np.concatenate([[SPECS[name].lo] * SPECS[name].size for name in names])
    hi = np.concatenate([[SPECS[name].hi] * SPECS[name].size for name in names])
    return lo, hi


def by_control(names, flat) -> dict:
    """Split a flat vector of control components (in `names` order) into {name: float, or list of 3}."""
    out, k = {}, 0
    for name in names:
        size = SPECS[name].size
        out[name] = [float(v) for v in flat[k : k + size]] if size == 3 else float(flat[k])
        k += size
    return out


def as_values(name: str, value) -> list[float]:
    """A control's value as a list of its size (a single number for an RGB control means grey)."""
    spec = SPECS[name]
    values = [float(v) for v in value] if isinstance(value, (list, tuple)) else [float(value)]
    if spec.size == 3 and len(values) == 1:
        values = values * 3
    if len(values) != spec.size:
        raise ValueError(f"{name} takes {spec.size} value(s), got {len(values)}: {values}")
    return values
