"""Uncertainties of the fitted controls from the curvature of the loss at the estimate, and identifiability.

From the loss linearised at the estimate (`linearize.py`: weighted residuals r, their Jacobian A by the fitted
control components, loss weights w, N residuals, p components), the classical covariance of nonlinear least
squares, plus the Monte Carlo error of the estimate itself:

    Cov(x) ≈ s² H⁻¹ + Cov_MC,     H = Σ w aᵢaⱼ (`Linearization.curvature`),
    s² = Σ w (r² − Var_MC) / (N − p),

s² measures what the target scatters by around the model (its own noise and any misfit): Var_MC, the Monte
Carlo variance of our own render of each residual, is removed from it (s² is averaged over the refinement's
later linearisations, H taken from the Jacobians of its last eight, and over random realisations also from the
realisation term's, realisations.py). s² H⁻¹ treats the residuals as
independent, but a pixel's three channels share their paths; the statistical term is therefore taken to
correlate within a pixel as our render's noise does, measured from the difference of its two passes
(`Linearization.statistical_covariance`). The estimate is the mean of m Gauss–Newton end points, each moved by
its linearisation's render noise; Cov_MC is that mean's covariance (`refine.mean_covariance`). After Adam alone
it is left out.

Model error: a target made by another renderer differs from ours in brightness (docs/benchmarks.md, "Against
other renderers": Cycles and warp-hair within 0.5% on a draped swatch, Mitsuba within 0.3% once its hair
sampler's residual lobe is corrected and up to 2% brighter as shipped, docs/MODEL.md), and the fit
turns that into controls, most into a light hair's albedo, whose image hardly changes with it. No number of
samples averages that away, so it is a term of its own: with ε the relative brightness disagreement
(`FitSettings.model_error`) and s the estimate's change per unit ε (`brightness_sensitivity`),

    Cov(x) += ε² s sᵀ,

reported apart as well (`Uncertainty.parts`, a fit's `uncertainty_parts`), so that it shows which part of a σ
is noise and which the renderers' disagreement. The correlations and their warnings come from the noise part
alone: they say how the images constrain the controls, and the rank-one model term would read as a trade-off
that no extra view undoes.

Realisation: where the target's fibers are known by their recipe only (`realisations = "random"`,
realisations.py), the target's strands are one draw of it, and the estimate would differ with another: that
spread, Cov_real, measured from K realisations rendered at the fitted look, is a term of its own as well,

    Cov(x) += Cov_real,

reported apart (`parts["realisation"]`); s² then leaves the realisations' own variance out, so that the noise
term does not count it a second time.

Directions the images do not pin: the curvature H is estimated from noisy Jacobians, crossed between independent
renders so that their noise does not add to it (`linearize.crossed_curvature`). Where a control's column is mostly
noise, as β_n's on an opaque swatch averaged over the layers' places, H's value along that direction is zero within
its standard error, or below it; every σ above would then come from noise divided by noise (the fallback to the
Jacobians' own product counts their noise as curvature: on blender_thick it made β_n 0.121 ± 0.018 for a true 0.36).
`pinned` splits the crossed H into its eigen-directions and tests each value against its jackknife error
(`linearize.curvature_directions`): those less than DETERMINED_Z errors above zero are left out of H (every term
above is then zero along them), and σ along them is what the controls' ranges allow: the estimate along such a
direction is where the steps stopped, not the images' value, so σ² there is the mean square distance from it to a
look anywhere along the direction within the ranges (`range_covariance`, reported apart as `parts["range"]`, with
a warning that names the direction).

Identifiability: two components whose estimates correlate by |ρ| > 0.95 trade off against each other in these
images (albedo and β_n can, through the albedo inversion, under a single front light); a control the images do
not change with has a zero column in A. Both end in `Uncertainty.warnings` with what to do about them.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np

from .latents import SPECS, by_control, component_bounds, flat_values
from .linearize import DETERMINED_Z, Linearization, curvature_directions, inverse_curvature

CORRELATION_WARNING = 0.95
# The relative brightness disagreement assumed for a target warp-hair did not render: the measured disagreement
# on a draped swatch at full depth is within 0.5% for Cycles and 0.3% for Mitsuba with its residual-lobe
# sampling corrected, 2% for Mitsuba 3.9.1 as shipped on light hair lit from the front (docs/benchmarks.md,
# "Against other renderers"), so 1% is the size of what a peer renderer (or a photograph, whose light level
# and camera response are known no better) brings. Our own targets have none: the same renderer made them.
PEER_MODEL_ERROR = 0.01


def target_model_error(target, model_error: float | None = None) -> float:
    """The model error counted for `target`: `model_error` when given, else 0 for a target warp-hair rendered
    and PEER_MODEL_ERROR for any other (another renderer's, or one of unknown origin: `Target.origin`)."""
    if model_error is not None:
        return float(model_error)
    return 0.0 if target.origin == "warp-hair" else PEER_MODEL_ERROR


def check_model_error(value, where: str = "model_error") -> None:
    """A relative brightness disagreement: a finite number >= 0, or None for the target's default."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(
            f"{where} must be a finite number >= 0 (a relative brightness disagreement, e.g. 0.01 for "
            f"1%; 0 for none), got {value!r}"
        )


def brightness_sensitivity(lin: Linearization) -> np.ndarray:
    """(p,): how far the least-squares estimate moves per unit ε when the target is (1 + ε) times as bright.

    The loss is Σ w ρ² with ρ = ω (gain·I(x) − T) (ω the loss's own weights, `linearize.loss_weights`). Near the
    linearisation point x̂, with r = ω (gain·I(x̂) − T), A = ∂r/∂x and t = ω T (`lin.targets`), the target
    (1 + ε) T gives ρ ≈ r + A δx − ε t, and the normal equations Aᵀ W (r + A δx − ε t) = 0 give

        δx(ε) = δx(0) + ε s,    s = (Aᵀ W A)⁻¹ Aᵀ W t.

    Scaling T also scales ω, but by 1/(1 + ε) for every residual alike (L2's 1/sqrt(mean T²) per image,
    relative L2's 1/(T + ε' mean T)), and a common factor on the loss does not move its minimum. At the
    least-squares estimate itself Aᵀ W r = 0, so there Aᵀ W t = Aᵀ W m with m = ω gain·I(x̂) = r + t, our own
    render as the residuals weigh it; evaluated anywhere else (at the truth, in `identify`; at a fit's end, one
    linearisation's noise away from it) the target form would add the Gauss–Newton step still to take,
    −H⁻¹ Aᵀ W r, which is noise, and large where two controls trade off. So s = H⁻¹ Aᵀ W m, with H the unbiased
    curvature and Aᵀ W m crossed between passes (`Linearization.crossed`), as the gradient is. A brighter target
    moves a control the way that brightens our render (s > 0 for albedo). Where `exposure` is fitted its column
    is ω·I = m / gain: s is then gain along exposure and zero along the rest (exactly for one linearisation's
    two passes, up to the earlier Jacobians' noise when they are pooled in): exposure absorbs the disagreement."""
    if lin.targets is None:
        raise ValueError(
            "the linearisation carries no target values (Linearization.targets): the sensitivity "
            "to a brightness disagreement needs them"
        )
    return inverse_curvature(lin.curvature) @ lin.crossed(lin.residuals + lin.targets)


def component_labels(names) -> list[str]:
    labels = []
    for name in names:
        labels += [f"{name}[{'rgb'[k]}]" for k in range(3)] if SPECS[name].size == 3 else [name]
    return labels


@dataclass(frozen=True)
class Unpinned:
    """The directions of the fitted components that the images do not determine at the fit's noise (`pinned`)."""

    vectors: np.ndarray  # (p, m): orthonormal columns, in the components' own units
    values: np.ndarray  # (m,): the crossed curvature along each
    errors: np.ndarray  # (m,): its standard error


def pinned(lin: Linearization) -> tuple[Linearization, Unpinned | None]:
    """(`lin` with its curvature restricted to the directions its Jacobians determine, the others), or (`lin`, None)
    unchanged where every direction is determined or there are too few Jacobians to tell (module docstring,
    "Directions the images do not pin")."""
    jacobians = lin.all_jacobians
    if len(jacobians) < 3:
        return lin, None
    values, vectors, errors = curvature_directions(jacobians, lin.loss_weights)
    weak = values < DETERMINED_Z * errors
    if not weak.any():
        return lin, None
    kept = vectors[:, ~weak]
    restricted = (kept * values[~weak]) @ kept.T
    return dataclasses.replace(lin, curvature=restricted), Unpinned(vectors[:, weak], values[weak], errors[weak])


def range_covariance(values: dict, unpinned: Unpinned) -> np.ndarray:
    """(p, p): Σ_v E[t²] v vᵀ over the directions v the images leave free, t uniform along the chord of the controls'
    ranges through the estimate x̂ in direction v (x̂ + t v within every control's range): the mean square distance
    from x̂ to a look anywhere along v, for x̂ is not the images' choice along it (at a range's middle width²/12, at
    its end width²/3). Components a direction hardly moves, and controls without an upper end (exposure), bound the
    chord only where they reach an end; along a chord without ends σ² is infinite."""
    x = flat_values(values)
    lo, hi = component_bounds(list(values))
    covariance = np.zeros((len(x), len(x)))
    for v in unpinned.vectors.T:
        moves = np.abs(v) > 1e-9
        ends = np.stack([(lo - x)[moves] / v[moves], (hi - x)[moves] / v[moves]])
        low, high = float(np.max(ends.min(axis=0))), float(np.min(ends.max(axis=0)))
        if not np.isfinite(high - low):
            covariance[moves, moves] = np.inf
            continue
        mean_square = (high**3 - low**3) / (3.0 * (high - low)) if high > low else 0.0
        covariance += mean_square * np.outer(v, v)
    return covariance


def _unpinned_warning(labels, unpinned: Unpinned, sigma: np.ndarray) -> str:
    directions = []
    for column, value, error in zip(unpinned.vectors.T, unpinned.values, unpinned.errors):
        order = np.argsort(-np.abs(column))
        main = [f"{column[i]:+.2f} {labels[i]}" for i in order if abs(column[i]) >= 0.3]
        directions.append(f"{' '.join(main)} (its curvature {value:.2g} ± {error:.2g})")
    loose = [f"{label} ±{s:.2g}" for label, s in zip(labels, sigma) if s > 0]
    return (
        f"the images do not determine {'; '.join(directions)} at the fit's noise: along "
        f"{'it' if len(directions) == 1 else 'them'} the value is not the images' but where the steps stopped, and "
        f"σ there is the controls' range's ({', '.join(loose)}). To pin it: more samples (--spp, --batch), another "
        "view or light, or fix one of the controls (--fix NAME=VALUE)"
    )


@dataclass(frozen=True)
class Uncertainty:
    """Each fitted control's 1σ (`uncertainties`, shaped as the values), its noise and model-error parts, the
    correlations between the components of different controls ("a/b" → ρ, from the noise part) and the
    identifiability warnings."""

    uncertainties: dict
    parts: dict
    correlations: dict
    warnings: tuple[str, ...]
    undetermined: tuple[str, ...] = ()  # the components that do not change the images: their σ says nothing


def estimate_uncertainty(
    lin: Linearization,
    mc_covariance: np.ndarray | None = None,
    model_error: float = 0.0,
    realisation_covariance: np.ndarray | None = None,
    brightness_from: Linearization | None = None,
    birge: float = 1.0,
    unpinned: Unpinned | None = None,
) -> Uncertainty:
    """The uncertainties at the linearisation's values (see the module docstring). mc_covariance: the
    estimate's own Monte Carlo covariance (`refine`); None leaves it out. model_error: ε, the relative
    brightness disagreement between the target's renderer and ours; 0 adds nothing, and the uncertainties are
    the noise's alone. realisation_covariance: the estimate's spread over the target's fiber realisations
    (realisations.py); None for a target whose strands are known. brightness_from: the linearisation whose
    estimate's change per unit ε makes the model term (`brightness_sensitivity`); None takes `lin` (a fit over
    realisations passes its pooled one). birge: S = √(χ²/dof) where the images differ from the fitted look by
    more than noise (goodness.py); it scales the parts that the residuals' own scatter s² does not already
    scale (the refinement's Monte Carlo error, the model error, the realisation term), so that every part of
    σ grows by S, the noise part through s². unpinned: the directions the images do not determine (`pinned`, whose
    restricted curvature `lin`, `brightness_from` and the realisation term then carry): σ along them is the
    controls' range's, and the refinement's Monte Carlo error is taken off them."""
    names = list(lin.values)
    A = lin.mean_jacobian
    p = A.shape[1]
    labels = component_labels(names)
    flat = np.abs(A).max(axis=0) == 0
    warnings = [
        f"{label} does not change the rendered images at all: it cannot be fitted from this target"
        for label in np.array(labels)[flat]
    ]
    cov = lin.statistical_covariance
    if mc_covariance is not None:
        if unpinned is not None:
            determined = np.eye(p) - unpinned.vectors @ unpinned.vectors.T  # the projector onto the pinned directions
            mc_covariance = determined @ mc_covariance @ determined
        cov = cov + birge**2 * mc_covariance
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    source = lin if brightness_from is None else brightness_from
    sensitivity = brightness_sensitivity(source) if source.targets is not None else None
    if model_error and sensitivity is None:
        raise ValueError("model_error > 0 needs the linearisation's target values (Linearization.targets)")
    model = birge * np.abs(model_error * sensitivity) if model_error else np.zeros(p)
    realised = np.zeros(p)
    if realisation_covariance is not None:
        realised = birge * np.sqrt(np.maximum(np.diag(realisation_covariance), 0.0))
    ranged = np.zeros(p)
    if unpinned is not None:
        ranged = np.sqrt(np.maximum(np.diag(range_covariance(lin.values, unpinned)), 0.0))
        warnings.append(_unpinned_warning(labels, unpinned, ranged))
    parts = {
        "model_error": float(model_error),
        "noise": by_control(names, sigma),
        "model": by_control(names, model),
        "realisation": None if realisation_covariance is None else by_control(names, realised),
        # Along the directions the images do not determine: the controls' ranges (`range_covariance`).
        "range": None if unpinned is None else by_control(names, ranged),
        # The estimate's change were the target 1% brighter (s · 0.01), signed.
        "shift_per_percent_brightness": None if sensitivity is None else by_control(names, 0.01 * sensitivity),
    }
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cov / np.outer(sigma, sigma)
    owners = [label.split("[")[0] for label in labels]
    correlations = {}
    for i, j in itertools.combinations(range(p), 2):
        if owners[i] == owners[j] or not np.isfinite(rho[i, j]):
            continue
        correlations[f"{labels[i]}/{labels[j]}"] = float(rho[i, j])
        # A component the images leave free along some direction has its own warning (`_unpinned_warning`).
        if abs(rho[i, j]) > CORRELATION_WARNING and ranged[i] <= sigma[i] and ranged[j] <= sigma[j]:
            warnings.append(
                f"{labels[i]} and {labels[j]} trade off in these images (correlation {rho[i, j]:+.3f}): a change of "
                f"one is largely compensated by the other, and their uncertainties (±{sigma[i]:.2g}, "
                f"±{sigma[j]:.2g}) lie mostly along that trade-off. To tell them apart, add an image under another "
                "light or from another view (a back-lit one shows transmission), or fix one of them."
            )
    # The diagonal of cov + ε² s sᵀ + Cov_real (+ the range's along free directions); with ε = 0, no realisation
    # term and every direction determined, the noise's σ as it stands.
    some = model_error or realisation_covariance is not None or unpinned is not None
    total = np.sqrt(sigma**2 + model**2 + realised**2 + ranged**2) if some else sigma
    uncertainties = by_control(names, total)
    return Uncertainty(uncertainties, parts, correlations, tuple(warnings), tuple(np.array(labels)[flat]))
