"""The artist controls θ of the hair model as one flat table of named values (in the spirit of `mi.traverse`).

Each control is defined here once: its name, size (1, or 3 for RGB), the columns it fills in θ (the vector the
gradient tracer differentiates, THETA_SIZE = 8 wide), its allowed range, its default, the colour input it
belongs to, its unit and what it does, and how the fit and gradcheck move it. Built from it: `HairParams` (one
field per control, its constructor and checks), the command line's hair flags, the fit's latents
(`optimize.latents.SPECS`), gradcheck's steps and the Jacobian's columns; `render_grad`, the torch front and the
fit name θ through it. Adding a control: one entry in CONTROLS, plus its physics (see the comment above it).

    from warp_hair.controls import CONTROLS, controls_of, named_theta, theta_vector
    CONTROLS["eta"].interval                      # '(1.0, 10.0]'
    controls_of("melanin")                        # ('eumelanin', 'pheomelanin', 'beta_m', ..., 'r_roughness_scale')
    named_theta("albedo", g)                      # {'albedo': g[..., 0:3], 'beta_m': g[..., 3], ...}
    theta_vector("albedo", params.to_dict())      # the 8 floats of θ

θ: columns 0-2 hold the colour, as the scene gives it (albedo RGB, σ_a RGB, or eumelanin and pheomelanin with
column 2 unused), then one column per scalar control. Exactly one colour input is given per material, so the
colour controls of different inputs share columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# Absorption (σ_a, or a melanin concentration) beyond this is black to float32 precision, and σ_a times a path
# length must stay finite.
ABSORPTION_MAX = 1e30

COLOUR_INPUTS = ("albedo", "sigma_a", "melanin")


# Below this roughness the lobes are narrower than float32 angles can resolve, and at 0 the mappings give
# v = s = 0 (a delta lobe no path tracer can sample). pbrt, Mitsuba and Cycles clamp the same way.
BETA_FLOOR = 0.01


@dataclass(frozen=True)
class Control:
    """One artist control: where it sits in θ, what values it takes, and what it means.

    Beyond the range: `floor` (a value below it renders as the floor, with a warning), `float32` (the kernels read
    the value as float32, and the range must hold there too), and what the fit and gradcheck do with it:
    `fit_hi` and `fit_start` (the open interval the fit's latent maps onto, and its neutral start; by default the
    range, above `floor`, and the default) and `gradcheck_move`, `gradcheck_step` (how `warp-hair gradcheck`
    moves the control for its target, and its finite-difference step).
    """

    name: str
    size: int  # 1, or 3 for an RGB control
    columns: tuple  # its columns of θ, one per component
    lo: float
    hi: float
    lo_open: bool
    hi_open: bool
    default: float | None  # None: no default (a colour input is given); a melanin's: when only the other is
    colour_input: str | None  # the colour input it belongs to, None for the scalar controls
    unit: str
    doc: str
    floor: float | None = None
    float32: bool = False
    fit_hi: float | None = None
    fit_start: float | None = None
    gradcheck_move: tuple = ("add", 0.0)  # ("scale", factor) or ("add", amount)
    gradcheck_step: float = 0.0

    @property
    def interval(self) -> str:
        """The allowed range as HairParams' errors state it, e.g. "(0.0, 1.0]"."""
        return f"{'(' if self.lo_open else '['}{self.lo}, {self.hi}{')' if self.hi_open else ']'}"

    def contains(self, value: float) -> bool:
        above_lo = value > self.lo if self.lo_open else value >= self.lo
        below_hi = value < self.hi if self.hi_open else value <= self.hi
        return above_lo and below_hi

    def check(self, value: float, label: str | None = None) -> None:
        """A ValueError naming the control (or `label`, e.g. "albedo[g]") and its range if value is outside (or,
        for a `float32` control, if its float32 is)."""
        if not self.contains(value):
            raise ValueError(f"{label or self.name} = {value} is outside the allowed range {self.interval}")
        if self.float32 and not self.contains(float(np.float32(value))):
            raise ValueError(
                f"{label or self.name} = {value} is outside the allowed range {self.interval} in float32, the "
                f"precision the renderer uses: it rounds to {float(np.float32(value))}"
            )

    @property
    def fit_lo(self) -> float:
        """The lower end of the fit's open interval: below the floor the renderer clamps, the loss is flat."""
        return self.lo if self.floor is None else self.floor


def _control(
    name,
    size,
    first_column,
    lo,
    hi,
    lo_open=False,
    hi_open=False,
    default=None,
    colour_input=None,
    unit="",
    doc="",
    **more,
):
    return Control(
        name,
        size,
        tuple(range(first_column, first_column + size)),
        lo,
        hi,
        lo_open,
        hi_open,
        default,
        colour_input,
        unit,
        doc,
        **more,
    )


# One entry per control. Adding one: an entry here, and its physics (the mapping to the model's coefficients in
# model/params.py and hair_bsdf.py, its column of the BSDF's Jacobian in model/jacobian.py). HairParams, the
# command line's flags, the fit's latents and gradcheck are built from this table.
CONTROLS = {
    control.name: control
    for control in (
        _control(
            "albedo",
            3,
            0,
            0.0,
            1.0,
            lo_open=True,
            colour_input="albedo",
            unit="fraction",
            doc="multiple-scattering albedo per channel; σ_a follows from the albedo inversion, which depends on β_n",
            fit_start=0.5,
            gradcheck_move=("scale", 0.9),
            gradcheck_step=0.04,
        ),
        # The absorptions' upper limit guards float32, it is no bound a fit can reach: the log map suits them.
        _control(
            "sigma_a",
            3,
            0,
            0.0,
            ABSORPTION_MAX,
            colour_input="sigma_a",
            unit="1 / fiber radius",
            doc="absorption coefficient per channel",
            fit_hi=math.inf,
            fit_start=1.0,
            gradcheck_move=("scale", 1.1),
            gradcheck_step=0.04,
        ),
        _control(
            "eumelanin",
            1,
            0,
            0.0,
            ABSORPTION_MAX,
            default=0.0,
            colour_input="melanin",
            unit="concentration",
            doc="dark pigment (blonde ≈ 0.3, brown ≈ 1.3, black ≈ 8)",
            fit_hi=math.inf,
            fit_start=1.0,
            gradcheck_move=("scale", 1.1),
            gradcheck_step=0.05,
        ),
        _control(
            "pheomelanin",
            1,
            1,
            0.0,
            ABSORPTION_MAX,
            default=0.0,
            colour_input="melanin",
            unit="concentration",
            doc="red pigment",
            fit_hi=math.inf,
            fit_start=0.3,
            gradcheck_move=("scale", 1.1),
            gradcheck_step=0.05,
        ),
        _control(
            "beta_m",
            1,
            3,
            0.0,
            1.0,
            default=0.3,
            unit="",
            floor=BETA_FLOOR,
            doc="longitudinal roughness (below BETA_FLOOR = 0.01 it renders as the floor)",
            fit_start=0.5,
            gradcheck_move=("add", 0.05),
            gradcheck_step=0.04,
        ),
        _control(
            "beta_n",
            1,
            4,
            0.0,
            1.0,
            default=0.3,
            unit="",
            floor=BETA_FLOOR,
            doc="azimuthal roughness (below BETA_FLOOR = 0.01 it renders as the floor)",
            fit_start=0.5,
            gradcheck_move=("add", 0.05),
            gradcheck_step=0.08,
        ),
        _control(
            "alpha",
            1,
            5,
            -30.0,
            30.0,
            default=2.0,
            unit="degrees",
            doc="cuticle scale tilt; > 0 (human hair) moves the primary highlight toward the root",
            gradcheck_move=("add", 3.0),
            gradcheck_step=1.0,
        ),
        # Above 1 (a fiber that refracts), in float32 too: at η = 1 the BSDF is not finite. 10 is beyond every
        # dielectric in visible light (diamond 2.4, silicon ~4).
        _control(
            "eta",
            1,
            6,
            1.0,
            10.0,
            lo_open=True,
            default=1.55,
            unit="",
            doc="index of refraction",
            float32=True,
            gradcheck_move=("add", 0.05),
            gradcheck_step=0.04,
        ),
        # 1e-6 to 1e6 spans any species by far, and the lobes are tested finite there. The fit bounds it below
        # only: its upper limit is far beyond any fit, and the log map suits a scale.
        _control(
            "r_roughness_scale",
            1,
            7,
            1e-6,
            1e6,
            default=1.0,
            unit="factor",
            doc="the species control: a factor on the R lobe's longitudinal variance only",
            fit_hi=math.inf,
            gradcheck_move=("add", 0.1),
            gradcheck_step=0.4,
        ),
        # Hair as it grows (model/variation.py, docs/MODEL.md "Strand-to-strand and root-to-tip variation"): each
        # strand's random value u in [0, 1] scales its look by 1 + 2(u − ½)·spread, as Cycles' Principled Hair
        # `Random Color` and `Random Roughness` do; the tip's absorption ramps in over the last tip_length of the
        # strand. Their defaults are no variation, where every strand renders as the material (bit for bit).
        # A spread's first-order effect averages out over strands, so the fit starts it inside the range.
        _control(
            "color_spread",
            1,
            8,
            0.0,
            1.0,
            default=0.0,
            unit="fraction",
            doc="strand-to-strand spread of the pigment: a melanin look's as Cycles' Random Color, else of σ_a",
            fit_start=0.25,
            gradcheck_move=("add", 0.1),
            gradcheck_step=0.05,
        ),
        _control(
            "roughness_spread",
            1,
            9,
            0.0,
            1.0,
            default=0.0,
            unit="fraction",
            doc="strand-to-strand spread of β_m and β_n together, as Cycles' Random Roughness",
            fit_start=0.25,
            gradcheck_move=("add", 0.1),
            gradcheck_step=0.05,
        ),
        # The log map suits a factor; 1e-3 to 1e3 spans bleached to dyed ends by far.
        _control(
            "tip_absorption",
            1,
            10,
            1e-3,
            1e3,
            default=1.0,
            unit="factor",
            doc="the tip's absorption over the root's (< 1: lighter tips), reached at the tip",
            fit_hi=math.inf,
            # From 1, where a tip's factor trades off against the colour with the ramp over most of the strand,
            # the descent wandered off along that valley (docs/acceptance.md, issue 44); lighter tips are the
            # common case.
            fit_start=0.7,
            gradcheck_move=("scale", 0.8),
            gradcheck_step=0.1,
        ),
        _control(
            "tip_length",
            1,
            11,
            0.0,
            1.0,
            lo_open=True,
            default=0.5,
            unit="fraction of the strand",
            doc="how far from the tip the absorption changes (linearly in arc length, from the root's to the tip's)",
            gradcheck_move=("add", 0.1),
            gradcheck_step=0.05,
        ),
    )
}

CONTROL_NAMES = tuple(CONTROLS)
# Hair as it grows (model/variation.py): a scene file or truth.json of a look without variation leaves them out.
VARIATION_CONTROLS = ("color_spread", "roughness_spread", "tip_absorption", "tip_length")
THETA_SIZE = 1 + max(column for control in CONTROLS.values() for column in control.columns)
COLOUR_CONTROLS = {
    colour_input: tuple(name for name, control in CONTROLS.items() if control.colour_input == colour_input)
    for colour_input in COLOUR_INPUTS
}
COLOUR_CONTROL_NAMES = tuple(name for names in COLOUR_CONTROLS.values() for name in names)
SCALAR_CONTROLS = tuple(name for name, control in CONTROLS.items() if control.colour_input is None)
RGB_CONTROLS = tuple(name for name, control in CONTROLS.items() if control.size == 3)


def column(name: str) -> int:
    """The θ column of a one-component control."""
    (k,) = CONTROLS[name].columns
    return k


def columns(name: str) -> list:
    """The θ columns of a control, as a list (a NumPy index that keeps the axis)."""
    return list(CONTROLS[name].columns)


def _colour_input(colour_input: str) -> str:
    if colour_input not in COLOUR_CONTROLS:
        raise ValueError(f"unknown colour input {colour_input!r}; allowed: {list(COLOUR_INPUTS)}")
    return colour_input


def controls_of(colour_input: str) -> tuple:
    """The controls of a material with this colour input: its colour control(s), then the scalars."""
    return COLOUR_CONTROLS[_colour_input(colour_input)] + SCALAR_CONTROLS


def named_theta(colour_input: str, theta) -> dict:
    """Name the last axis of theta (..., THETA_SIZE) by control: {name: (..., 3) for RGB, (...) otherwise}, in
    `controls_of` order. The arrays are views of theta; a torch tensor stays one (on its device)."""
    if not hasattr(theta, "shape"):  # a NumPy array or a torch tensor is sliced as it is
        theta = np.asarray(theta)
    if theta.shape[-1:] != (THETA_SIZE,):
        raise ValueError(f"θ must have {THETA_SIZE} components on its last axis, got shape {theta.shape}")
    named = {}
    for name in controls_of(colour_input):
        first, *rest = CONTROLS[name].columns
        named[name] = theta[..., first : first + 1 + len(rest)] if rest else theta[..., first]
    return named


def theta_vector(colour_input: str, values: dict) -> list:
    """The THETA_SIZE floats of θ from every control of one colour input ({name: float, or 3 for RGB}); columns
    no control of the input fills are 0."""
    names = controls_of(colour_input)
    if set(values) != set(names):
        raise ValueError(f"θ of a {colour_input!r} material takes exactly {list(names)}, got {sorted(values)}")
    theta = [0.0] * THETA_SIZE
    for name in names:
        components = np.atleast_1d(np.asarray(values[name], dtype=np.float64))
        if components.shape != (CONTROLS[name].size,):
            raise ValueError(f"{name} takes {CONTROLS[name].size} value(s), got {values[name]!r}")
        for k, value in zip(CONTROLS[name].columns, components):
            theta[k] = float(value)
    return theta


def describe() -> str:
    """The table as text, one control a line (HairParams' docstring carries it)."""
    lines = []
    for c in CONTROLS.values():
        size = "RGB" if c.size == 3 else "scalar"
        default = "" if c.default is None else f", default {c.default}"
        unit = f" ({c.unit})" if c.unit else ""
        lines.append(f"{c.name}: {size} in {c.interval}{default}{unit}: {c.doc}")
    return "\n".join(lines)
