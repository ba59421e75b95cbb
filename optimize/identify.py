"""Whether a target's images identify its controls: the fit's expected uncertainty, before any fit is run.

    warp-hair targets check TARGET [--fit NAMES] [--at NAME=V ... | FIT_DIR/params.json] [--spp N] [--model-error E]

The loss is linearised at the target's true controls (truth.json, or given values: a look, or a fit's estimate
from its params.json, for a photo that has no truth) as the fit linearises it
(`linearize.py`: weighted, pooled residuals, their Jacobian A, loss weights W; CHECK_LINEARISATIONS of them at
CHECK_SPP per render, their Jacobians pooled). The target's own noise then moves the least-squares estimate by

    Cov_target = H⁻¹ Aᵀ W C W A H⁻¹,     H = Aᵀ W A,

C the covariance of the target's pooled pixels: the inverse of the target's Fisher information, the σ no fit of
these images can beat. Our render of the same scene has the target's noise per sample (the same paths, when
warp-hair made the target; a peer's sampling differs, and its noise is taken as ours), so C is our render's,
times CHECK_SPP / the target's spp (its scenes' [render] spp, or `spp`: the variance of a mean of n independent
samples falls as 1/n; `_target_gradient_covariance` says how it is measured).

A fit adds its own Monte Carlo error: its estimate is the mean of m Gauss–Newton end points (`refine.
averaged_points` of `fit.refine_steps`), each moved from the optimum by its step's render noise, H⁻¹ Aᵀ W r̄ with
r̄ the mean of two passes at the fit's samples per pixel (`fit.gauss_newton_spp`). So the fit's part is the same
sandwich with our render's own C, times CHECK_SPP / (2 · the fit's spp), over m. Where the fit renders about as
many samples in all as the target has, the two parts are alike, and a check without the fit's part promised more
than fits kept (docs/acceptance.md, "Photographs"). The Jacobians' own noise, which the fit's σ counts from its
points' scatter (`refine.mean_covariance`), is left out (about 3% of the expected σ on the photo-like swatches):
a lower bound.

The model-error part is the estimate's shift per relative brightness disagreement (`uncertainty.
brightness_sensitivity`, here over every linearisation's passes) times the model error counted for the target
(`uncertainty.target_model_error`: 0 for warp-hair's own targets, 1% for others). A target whose scenes give
its strands by their recipe only (target.toml `realisations = "random"`, optimize/realisations.py) adds the
realisation part: the target's strands are one draw of that recipe, which no fit of them can know, and the
estimate moves with the draw by as much as K further realisations, each linearised at the truth with both
passes on it, move it (`realisations.realisation_spread`, the fit's own realisation term; K
CHECK_REALISATION_SAMPLES, more than the fit's 8, whose spread is too uncertain to judge by). The rule: a
control is identified when its expected σ,
√(σ_target² + σ_fit² + (model error · shift per unit)² + σ_realisation²), is below its acceptance bound
(BOUNDS: albedo 0.02 a channel, β_m and β_n 0.03, what `benchmarks/fit_targets.py` holds fits to); a control
the images do not change with is not. Controls without a bound (α, η, exposure, ...) are reported, not judged.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from warp_hair.renderer.prepare import prepare

from . import camera
from .goodness import goodness_of_fit, quantisation_variances
from .latents import DEFAULT_FIT, SPECS, as_values, parse_control_names
from .linearize import CHANNELS, crossed_curvature, linearize
from .realisations import Realisations, check_mode, realisation_spread
from .refine import SEED_STRIDE, averaged_points
from .settings import BOUNDS, FitSettings, gauss_newton_spp, refine_steps
from .target import true_values
from .uncertainty import (
    CORRELATION_WARNING,
    check_model_error,
    component_labels,
    target_model_error,
)

CHECK_SPP = 64  # per render: the fit's final linearisations' (fit.FINAL_SPP_FACTOR × its default spp)
CHECK_LINEARISATIONS = 4  # their Jacobians pooled: H and A as steady as the refinement's
MANY_SAMPLES = 64  # a factor on a target's samples beyond which they are not offered as the remedy
CAMERA_BOUND = 0.02  # a photo's gain or white balance is pinned when its expected relative σ is below 2%
# A control is pinned when this many expected σ fit within its bound: a fit then lands within it about 19 times in
# 20. One whose σ alone fits is identified (the exit status) but only likely: within its bound about 2 times in 3.
PINNED_SIGMAS = 2.0
# Realisations the strands' draw part comes from. A spread estimated from K of them is uncertain by about
# 1/√(2(K − 1)) and more: at the fit's 8 the check of cycles_dark_straight put β_n's part at 0.0075 or 0.0152 by
# the seed alone, which flips its verdict; at 24, 0.0117 (docs/acceptance.md, "Strands the fit does not know").
CHECK_REALISATION_SAMPLES = 24


@dataclasses.dataclass(frozen=True)
class Identifiability:
    target: str
    origin: str  # who rendered it (`Target.origin`)
    values: dict  # the controls it was checked at
    labels: list  # one per fitted component, "albedo[r]", "beta_m", ...
    target_spp: list  # per image, the samples per pixel its noise was taken at
    noise: np.ndarray  # (p,) the expected σ from the target's own noise
    shift: np.ndarray  # (p,) the estimate's change were the target 1% brighter
    model_error: float  # relative; the model part of σ is model_error / 0.01 · |shift|
    correlation: list  # per component: (label of the other control's component most correlated, ρ) or None
    bounds: np.ndarray  # (p,) the acceptance bound, NaN where there is none
    camera: list = dataclasses.field(default_factory=list)  # a photo's unknowns: (label, value, relative σ)
    realisation: np.ndarray | None = None  # (p,) σ from the target's strands being one draw; None: fixed strands
    realisation_samples: int = 0  # K, the realisations that part comes from
    fit_noise: np.ndarray | None = None  # (p,) σ from the fit's own renders; None: the fit has no refinement
    fit_points: int = 0  # m, the Gauss–Newton end points the fit averages
    fit_spp: int = 0  # samples per pixel of each of their renders
    problems: list = dataclasses.field(default_factory=list)  # what keeps a control from being identified
    # The measure of fit at the checked controls (goodness.py): what a fit landing there should show; well above
    # 1 where the scenes do not describe the images even at these controls.
    goodness: object | None = None
    # A photographed target (`is_photo`): its remedies are a photographer's, not more samples of a render.
    photo: bool = False
    gains: str = "none"  # the target's gains (optimize/camera.py): what pins them is a remedy
    card: bool = False  # a grey card in it (marked or rendered) pins them already
    views: int = 1
    arrangement: tuple = ()  # the keys of the target's [arrangement] prior, which the strands' draw includes
    quantisation: np.ndarray | None = None  # (p,) the part of σ target noise from the photos' 8- or 16-bit codes

    @property
    def sigma(self) -> np.ndarray:
        """The expected σ of a fit: the target's noise, the fit's own renders, the model error and the target's
        strands' draw together."""
        realised = 0.0 if self.realisation is None else self.realisation**2
        fitted = 0.0 if self.fit_noise is None else self.fit_noise**2
        return np.sqrt(self.noise**2 + fitted + (self.model_error / 0.01 * self.shift) ** 2 + realised)

    @property
    def identifiable(self) -> bool:
        return not self.problems

    @property
    def verdicts(self) -> list:
        """Per component, `verdict` of its expected σ against its bound."""
        return [verdict(s, bound) for s, bound in zip(self.sigma, self.bounds)]

    def table(self) -> str:
        realised, fitted = self.realisation is not None, self.fit_noise is not None
        header = (
            "control",
            "value",
            "σ target noise",
            *(("σ fit's renders",) if fitted else ()),
            "shift per 1% brighter",
            *(("σ strands' draw",) if realised else ()),
            "σ expected",
            "bound",
            "verdict",
            "largest correlation",
        )
        values = np.concatenate([np.atleast_1d(v) for v in self.values.values()])
        rows = []
        for k, label in enumerate(self.labels):
            other = self.correlation[k]
            rows.append(
                (
                    label,
                    f"{values[k]:.3f}",
                    f"{self.noise[k]:.4f}",
                    *((f"{self.fit_noise[k]:.4f}",) if fitted else ()),
                    f"{self.shift[k]:+.4f}",
                    *((f"{self.realisation[k]:.4f}",) if realised else ()),
                    f"{self.sigma[k]:.4f}",
                    "" if np.isnan(self.bounds[k]) else f"{self.bounds[k]:g}",
                    self.verdicts[k],
                    "" if other is None else f"{other[1]:+.2f} with {other[0]}",
                )
            )
        widths = [max(len(r[i]) for r in [*rows, header]) for i in range(len(header))]
        lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in [header, *rows]]
        lines.insert(1, "  ".join("-" * w for w in widths))
        return "\n".join(lines)

    def camera_table(self) -> str:
        """The photo's gains and white balance (camera.py): each pinned when its expected relative σ is below
        CAMERA_BOUND."""
        if not self.camera:
            return ""
        lines = [
            f"camera unknowns (fitted with the hair; pinned when the expected σ is below {100 * CAMERA_BOUND:g}%):"
        ]
        for label, value, sigma in self.camera:
            verdict = (
                "pinned"
                if sigma < CAMERA_BOUND
                else "not pinned: it trades off with the hair"
                + (
                    " (a grey card in the shot pins it: targets photo --card-mask)"
                    if self.photo and not self.card
                    else ""
                )
            )
            lines.append(f"  {label:<18} {value:.4f}  σ {100 * sigma:.2f}%  {verdict}")
        return "\n".join(lines)

    def summary(self) -> str:
        drawn = "" if self.realisation is None else " + σ strands' draw²"
        fitted = (
            ""
            if self.fit_noise is None
            else f" + σ fit's renders² (the mean of {self.fit_points} Gauss-Newton points at {self.fit_spp} spp)"
        )
        rule = (
            f"σ expected = √(σ target noise²{fitted} + ({100 * self.model_error:g}% model error · shift per 1%)²"
            f"{drawn}), below its bound for every control"
        )
        likely = [label for label, verdict in zip(self.labels, self.verdicts) if verdict == "likely"]
        if self.identifiable and likely:
            return (
                f"identifiable: {rule}; pinned (a fit within the bound about 19 times in 20: {PINNED_SIGMAS:g} σ "
                f"within it) but for {', '.join(likely)}, within the bound only about 2 times in 3"
            )
        if self.identifiable:
            return f"identifiable and pinned (a fit within the bound about 19 times in 20): {rule}"
        return "not identifiable (" + rule + " fails):\n" + "\n".join(f"  {p}" for p in self.problems)


def verdict(sigma: float, bound: float) -> str:
    """ "pinned" where PINNED_SIGMAS expected σ are within the bound, "likely" where one σ is, else "not pinned";
    "" for a control without a bound."""
    if np.isnan(bound):
        return ""
    if PINNED_SIGMAS * sigma <= bound:
        return "pinned"
    return "likely" if sigma < bound else "not pinned"


def check_target(
    target,
    values: dict | None = None,
    controls=DEFAULT_FIT,
    spp: int | None = None,
    model_error: float | None = None,
    render_spp: int = CHECK_SPP,
    linearisations: int = CHECK_LINEARISATIONS,
    seed: int = 0,
    threads=None,
    settings=None,
    scenes=None,
    realisations: str | None = None,
    realisation_samples: int = CHECK_REALISATION_SAMPLES,
) -> Identifiability:
    """Linearise the loss at the target's true controls (or `values`, {name: float or list}, which override
    them) and judge each fitted control (see the module docstring). spp: the samples per pixel the target's
    noise is taken at (default: each image's scene [render] spp, what it was rendered with); settings: the
    fit's (`FitSettings`: loss, pooling, Gauss–Newton steps and samples), default FitSettings(); scenes: the
    target's images' scenes, prepared; realisations: "fixed" or "random" as the fit's (default: the target's);
    realisation_samples: K, the further realisations the strands' draw part comes from."""
    names = parse_control_names(controls, target.hair.colour_input)
    check_model_error(model_error)
    if spp is not None and (not isinstance(spp, int) or isinstance(spp, bool) or spp < 1):
        raise ValueError(f"spp must be an integer >= 1, got {spp!r}")
    if not isinstance(linearisations, int) or linearisations < 2:
        raise ValueError(f"linearisations must be an integer >= 2, got {linearisations!r}")
    if not isinstance(realisation_samples, int) or isinstance(realisation_samples, bool) or realisation_samples < 2:
        raise ValueError(f"realisation samples must be an integer >= 2, got {realisation_samples!r}")
    random = check_mode(realisations or target.realisations) == "random"
    at = {name: as_values(name, v) for name, v in true_values(target, names).items()}
    at.update({name: as_values(name, v) for name, v in (values or {}).items()})
    missing = [name for name in names if name not in at]
    if missing:
        raise ValueError(
            f"{target.name}: no true value for {', '.join(missing)} (the target has "
            f"{'no truth.json' if target.truth is None else 'none in truth.json'}); give the look to check at: "
            "--at NAME=V ... (the look you expect), or a quick fit's estimate, --at FIT_DIR/params.json (e.g. "
            f"`warp-hair fit {target.directory} -o quick --iters 30 --refine 2`)"
        )
    unknown = sorted(set(at) - set(names))
    if unknown:
        raise ValueError(f"values given for {unknown}, which are not checked (checked: {list(names)})")
    for name in names:
        SPECS[name].check_start(at[name], "--at")
    at = {name: at[name] if SPECS[name].size == 3 else at[name][0] for name in names}
    settings = settings or FitSettings(controls=names)
    model_error = target_model_error(target, model_error)
    scenes = [prepare(image.scene) for image in target.images] if scenes is None else scenes

    lins = [
        linearize(target, at, settings, render_spp, seed + SEED_STRIDE * k, threads=threads, scenes=scenes)
        for k in range(linearisations)
    ]
    # Over random realisations, K more linearisations each on one further realisation give the realisation part,
    # and their Jacobians join the curvature's: where the images hardly change with a control (dark hair's β_n)
    # H from the 8 Jacobians alone is too noisy, and H⁻¹ too large on average (tests/test_identify.py).
    first = seed + SEED_STRIDE * linearisations
    others = (
        _realisation_linearisations(target, at, settings, render_spp, first, threads, realisation_samples)
        if random
        else []
    )
    jacobians = np.concatenate([lin.jacobians for lin in lins + others])
    w = lins[0].loss_weights
    h_inv = np.linalg.pinv(crossed_curvature(jacobians, w))
    total = jacobians.sum(axis=0)
    p = total.shape[1]

    target_spp = [image.scene.render.spp if spp is None else spp for image in target.images]
    factors = [render_spp / n for n in target_spp]
    quantisation = quantisation_variances(target, settings)
    gradient_cov = _target_gradient_covariance(lins, total / len(jacobians), factors, quantisation)
    cov = h_inv @ gradient_cov @ h_inv
    noise = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # `uncertainty.brightness_sensitivity` over every pass: each pass's render met with every other Jacobian.
    n = len(jacobians)
    renders = np.concatenate([lin.residuals + lin.targets for lin in lins + others])
    crossed = sum(((total - a) / (n - 1)).T @ (w * m) for a, m in zip(jacobians, renders)) / n
    shift = 0.01 * h_inv @ crossed

    labels = component_labels(names)
    owners = [label.split("[")[0] for label in labels]
    flat = np.abs(total).max(axis=0) == 0
    noise[flat] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cov / np.outer(noise, noise)
    correlation = [None] * p
    for i, j in itertools.permutations(range(p), 2):
        if (
            owners[i] != owners[j]
            and np.isfinite(rho[i, j])
            and (correlation[i] is None or abs(rho[i, j]) > abs(correlation[i][1]))
        ):
            correlation[i] = (labels[j], float(rho[i, j]))
    realisation, realisation_samples, draw = None, 0, None
    if random:
        covariance, draw, _ = realisation_spread(h_inv @ ((total / n) * w[:, None]).T, others)
        realisation, realisation_samples = np.sqrt(np.maximum(np.diag(covariance), 0.0)), len(others)
    fit_noise, fit_points, fit_spp, cov_fit = None, 0, 0, None
    steps = refine_steps(settings, target, max(target_spp))
    if steps:  # the fit's own renders (the module docstring)
        fit_spp, fit_points = gauss_newton_spp(settings, target), averaged_points(steps)
        fit_factors = [render_spp / (2 * fit_spp)] * len(target.images)
        gradient_fit = _target_gradient_covariance(lins, total / n, fit_factors)
        cov_fit = h_inv @ gradient_fit @ h_inv / fit_points
        fit_noise = np.sqrt(np.maximum(np.diag(cov_fit), 0.0))
        fit_noise[flat] = np.inf
    camera_unknowns = []
    projection = lins[0].camera
    if projection is not None:
        # The gains' covariance: the target's noise on them, and the hair's carried over (camera.Projection).
        normal_inv = np.linalg.pinv(projection.normal)
        gradient_gg = _target_gradient_covariance(lins, projection.columns, factors, quantisation)
        noise_gg = normal_inv @ gradient_gg @ normal_inv
        follow = -normal_inv @ (projection.columns.T @ (w[:, None] * projection.jacobian))
        if fit_noise is not None:  # the fit's own renders move the gains as they move the hair
            gradient_fit_gg = _target_gradient_covariance(lins, projection.columns, fit_factors)
            noise_gg += normal_inv @ gradient_fit_gg @ normal_inv / fit_points
            cov = cov + cov_fit
        if projection.direct is None:
            cov_gg = noise_gg + follow @ (cov + np.outer(shift, shift) * (model_error / 0.01) ** 2) @ follow.T
            is_gain = np.array([label.startswith("gain") for label in projection.labels], dtype=float)
            cov_gg += model_error**2 * np.outer(is_gain, is_gain)
        else:  # a grey card: the gains take part of a disagreement of the hair's brightness, and follow the hair's
            moved = projection.brightness(shift / 0.01)
            cov_gg = noise_gg + follow @ cov @ follow.T + model_error**2 * np.outer(moved, moved)
        values = camera.label_values(projection, target)
        camera_unknowns = [
            (label, float(v), float(np.sqrt(max(cov_gg[k, k], 0.0))))
            for k, (label, v) in enumerate(zip(projection.labels, values))
        ]
    quantised = None
    if quantisation is not None:
        cov_q = h_inv @ _target_gradient_covariance(lins, total / n, [0.0] * len(factors), quantisation) @ h_inv
        quantised = np.sqrt(np.maximum(np.diag(cov_q), 0.0))
    result = Identifiability(
        target=target.name,
        origin=target.origin,
        values=at,
        labels=labels,
        target_spp=target_spp,
        noise=noise,
        shift=shift,
        model_error=model_error,
        correlation=correlation,
        bounds=np.array([BOUNDS.get(owner, np.nan) for owner in owners]),
        camera=camera_unknowns,
        realisation=realisation,
        realisation_samples=realisation_samples,
        fit_noise=fit_noise,
        fit_points=fit_points,
        fit_spp=fit_spp,
        goodness=goodness_of_fit(lins[0], target, settings, render_spp, quantisation, draw),
        photo=is_photo(target),
        gains=target.gains,
        card=any(image.card is not None or image.scene.card is not None for image in target.images),
        views=len(target.images),
        arrangement=_arrangement_keys(target),
        quantisation=quantised,
    )
    # What keeps each control from being identified needs the whole account (its σ parts) first.
    return dataclasses.replace(result, problems=_problems(result, flat))


def _arrangement_keys(target) -> tuple:
    """The keys of the target's [arrangement] prior whose range is not a point (none without one)."""
    prior = getattr(target, "arrangement", None)
    return () if prior is None else tuple(k for k, (a, b) in prior.ranges.items() if b > a)


def _arrangement_hint(result) -> str:
    """Where the strands' draw includes a prior over how they lie: that part does not fall with more strands."""
    if not result.arrangement:
        return ""
    return (
        f"; part of it is how the strands lie (target.toml's [arrangement]: {', '.join(result.arrangement)}), which "
        "moves every strand at once and does not fall with more of them: narrow those ranges where you can measure "
        "the swatch (the gap between its layers, how evenly its strands lie, how far its clumps close)"
    )


def is_photo(target) -> bool:
    """Whether the target's images are photographs: decoded from a PNG, JPEG, TIFF or raw file, or an EXR that
    `warp-hair targets photo` wrote from one (its header's "photo" record)."""
    return any(image.from_photo for image in target.images)


def _realisation_linearisations(target, at, settings, render_spp, seed, threads, count) -> list:
    """`count` linearisations at `at`, each with both passes on one further realisation of the target's strands
    (those the fit's realisation term renders, realisations.py), from seed on."""
    pool = Realisations(target)
    return [
        linearize(target, at, settings, render_spp, seed + SEED_STRIDE * k, threads=threads, scenes=pool.term_scenes(k))
        for k in range(count)
    ]


def _target_gradient_covariance(lins, a, variance_factors, extra=None) -> np.ndarray:
    """(p, p): the covariance of Aᵀ W t from the target's noise, Σ over pooled pixels of aᵀ W C W a with C the
    pixel's 3×3 noise covariance. Each channel's variance is our render's, from each pixel's own samples
    (`Linearization.variances`, one pass at CHECK_SPP) times `variance_factors` (per image: our spp over the
    target's); the channels' correlation is that of the passes' half differences, pooled over the image. The
    half differences alone give a 3×3 covariance per pixel too, but from as many values as there are
    linearisations, and on highlight pixels, whose rare bright paths make the variance, these fall short of it
    in most draws (a check on a small target came out 0.19–0.24 for a σ of 0.235, with each pixel's own samples
    0.216–0.224). `extra` (N,): variances the target has besides its samples' (a photo's quantisation)."""
    variances = np.mean([lin.variances.mean(axis=0) for lin in lins], axis=0)
    halves = np.stack([0.5 * (lin.residuals[0] - lin.residuals[1]) for lin in lins])
    w, p = lins[0].loss_weights, a.shape[1]
    covariance, start = np.zeros((p, p)), 0
    for count, factor in zip(lins[0].image_residuals, variance_factors):
        part = slice(start, start + count)
        d = halves[:, part].reshape(-1, CHANNELS)
        products = d.T @ d
        scale = np.sqrt(np.diag(products))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = np.where(np.outer(scale, scale) > 0, products / np.outer(scale, scale), np.eye(CHANNELS))
        variance = factor * variances[part] + (0.0 if extra is None else extra[part])
        sd = np.sqrt(variance).reshape(-1, CHANNELS)
        weighted = (w[part, None] * a[part]).reshape(-1, CHANNELS, p) * sd[:, :, None]
        covariance += np.einsum("bcp,cd,bdq->pq", weighted, correlation, weighted)
        start += count
    return covariance


def _problems(result: Identifiability, flat: np.ndarray) -> list:
    """Per control that fails the rule, what fails and what would help: for a photographed target, what to
    photograph (`_photo_remedy`), for a render, what to render."""
    problems = []
    model = result.model_error / 0.01 * np.abs(result.shift)
    drawn = np.zeros(len(model)) if result.realisation is None else result.realisation
    fitted = np.zeros(len(model)) if result.fit_noise is None else result.fit_noise
    for k, label in enumerate(result.labels):
        bound, sigma = result.bounds[k], result.sigma[k]
        if flat[k]:
            problems.append(
                f"{label}: the images do not change with it at all; "
                + (
                    "photograph a view in which it shows (front- and back-lit: a light behind the swatch shows the "
                    "light that went through the fibers), or fix it (leave it out of --fit)"
                    if result.photo
                    else "add a view or a light in which it shows, or fix it"
                )
            )
            continue
        if np.isnan(bound) or sigma < bound:
            continue
        message = (
            f"{label}: expected σ {sigma:.3g} ≥ its bound {bound:g} (target noise {result.noise[k]:.3g}, "
            f"model error {model[k]:.3g}"
            + ("" if result.realisation is None else f", strands' draw {drawn[k]:.3g}")
            + ("" if result.fit_noise is None else f", the fit's renders {fitted[k]:.3g}")
            + ")"
        )
        rest = model[k] ** 2 + drawn[k] ** 2
        beyond_samples = rest >= bound**2  # what more samples of the target or the fit cannot remove
        if not beyond_samples and result.noise[k] ** 2 + rest < bound**2:  # the fit's own renders tip it
            steps = int(np.ceil(fitted[k] ** 2 / (bound**2 - result.noise[k] ** 2 - rest) * result.fit_points))
            message += (
                f"; the fit's own renders ({result.fit_points} averaged Gauss-Newton points at {result.fit_spp} "
                f"spp) add {fitted[k]:.3g}: fit with about {2 * steps} Gauss-Newton steps (--refine {2 * steps}; "
                "that part falls as one over the square root of the steps)"
            )
        elif beyond_samples and drawn[k] > model[k] and result.photo:
            message += (
                f"; the photographed strands, one draw of the recipe that no fit of them knows, alone move it by "
                f"{drawn[k]:.3g} (over {result.realisation_samples} realisations), and no longer exposure removes "
                "that: get more strands in view (a wider crop of the swatch, or the camera further back, or a wider "
                "swatch: that part falls about as one over the square root of the strands seen)"
                + _arrangement_hint(result)
            )
        elif beyond_samples and drawn[k] > model[k]:
            message += (
                f"; the target's strands, one draw of their recipe that no fit of them knows, alone move it by "
                f"{drawn[k]:.3g} (over {result.realisation_samples} realisations), and no number of samples removes "
                "that: show more strands (a wider swatch or more of it in view: that part falls about as one over "
                "the square root of the strands seen), or give the scenes the very strands and fit them (realisations "
                '= "fixed")' + _arrangement_hint(result)
            )
        elif beyond_samples and result.photo:
            message += (
                f"; a {100 * result.model_error:g}% brightness disagreement alone moves it by {model[k]:.3g}, "
                "and no longer exposure removes that: "
                + (
                    'fit the photos\' exposures (gains = "per-image" in target.toml, or "exif" where every photo '
                    "has its EXIF exposure), which absorb a uniform disagreement, or photograph a view in which it "
                    "changes the image otherwise than brightness does (front- and back-lit)"
                    if result.gains == "none"
                    else "photograph a view in which it changes the image otherwise than brightness does (front- "
                    "and back-lit: a light behind the swatch)"
                )
            )
        elif beyond_samples:
            message += (
                f"; a {100 * result.model_error:g}% brightness disagreement alone moves it by {model[k]:.3g}, "
                "and no number of samples removes that: fit exposure as well, which absorbs a uniform "
                "disagreement but may trade off against it (check with --fit ...,exposure), or add a view in "
                "which it changes the image otherwise than brightness does"
            )
        else:  # the target's own noise: more samples of it, the fit's part as it is where that leaves room
            room = bound**2 - rest - fitted[k] ** 2
            factor = result.noise[k] ** 2 / (room if room > 0 else bound**2 - rest)
            other = result.correlation[k]
            traded = other if other is not None and abs(other[1]) > CORRELATION_WARNING else None
            if result.photo:
                message += "; " + _photo_remedy(result, k, traded, rest, fitted[k])
                problems.append(message)
                continue
            spp = ", ".join(str(int(np.ceil(factor * n))) for n in sorted(set(result.target_spp)))
            samples = f"render the target with {factor:.2g}× the samples ({spp} spp; σ falls as 1/√spp)"
            if traded is not None:
                message += (
                    f"; it trades off with {traded[0]} (correlation {traded[1]:+.2f}): add a view that tells "
                    "them apart (a light from another side, another camera)"
                    + (
                        f", or {samples}"
                        if factor <= MANY_SAMPLES
                        else f"; more samples alone would take {factor:.2g}× as many"
                    )
                )
            else:
                message += f"; {samples}, or add another view (a light from another side, another camera)"
        problems.append(message)
    return problems


def _photo_remedy(result: Identifiability, k: int, traded, rest: float, fitted: float) -> str:
    """What a photographer can do where the photos' own noise leaves control k unpinned; `traded` is (the control
    it trades off with, ρ) or None, `rest` the variance no exposure removes (model error, strands' draw), `fitted`
    the fit's own renders' σ. A photo's noise does not change the fit's renders, so where they leave no room, the
    photos' part and theirs are each given half of what is left: more steps of the fit as well."""
    bound = result.bounds[k]
    room = bound**2 - rest - fitted**2
    steps = 0
    if room <= 0:
        room = (bound**2 - rest) / 2
        steps = 2 * int(np.ceil(fitted**2 / room * result.fit_points))
    factor = result.noise[k] ** 2 / room
    remedies = []
    if result.gains != "none" and not result.card:
        card = "a grey card in the shot (`targets photo --card-mask FILE --card-reflectance 0.18`)"
        exif = 'manual exposures with EXIF (gains = "exif": one gain, the views\' ratios known)'
        pins = f"{card} or {exif}" if result.gains == "per-image" and result.views > 1 else card
        remedies.append(f"fix the photos' gains, which the hair's brightness trades off with: {pins}")
    view = (
        "a back-lit view besides the front-lit one (a light behind the swatch)"
        if result.views == 1
        else "another view (a light from another side, or another camera angle)"
    )
    if traded is not None:
        remedies.append(
            f"it trades off with {traded[0]} (correlation {traded[1]:+.2f}): photograph {view} to tell them apart"
        )
    else:
        remedies.append(f"photograph {view}")
    remedies.append("more hair in view (the camera closer, or a wider swatch filling the frame: more pixels on it)")
    quantised = 0.0 if result.quantisation is None else result.quantisation[k]
    if quantised**2 > 0.5 * result.noise[k] ** 2:
        remedies.append(f"16-bit TIFF or raw photos (the 8-bit codes' rounding alone gives σ {quantised:.3g})")
    shots = int(np.ceil(factor))
    if factor <= MANY_SAMPLES:
        remedies.append(
            f"less noise in each photo: a longer exposure at a lower ISO, or about {shots} shots of each view "
            "averaged on a tripod (σ falls as one over the square root of the light gathered)"
        )
    else:
        remedies.append(f"less noise alone would take about {shots} shots of each view averaged")
    text = "; or ".join(remedies)
    if steps:
        text += (
            f"; the fit's own renders ({result.fit_points} averaged Gauss-Newton points at {result.fit_spp} spp) add "
            f"{fitted:.3g} through the same trade-offs, which better photos of the same views do not change: what "
            f"pins the hair better (a card, a view) shrinks both parts, and Gauss-Newton steps alone would take about "
            f"{steps} (--refine {steps})"
        )
    return text


def describe(result: Identifiability) -> str:
    """What `warp-hair targets check` prints."""
    by = {"warp-hair": "rendered by warp-hair", "unknown": "of unknown origin"}.get(
        result.origin, f"rendered by {result.origin}"
    )
    spp = ", ".join(f"{n}" for n in result.target_spp)
    head = (
        f"{result.target} ({by}; its noise taken at {spp} spp per image), checked at "
        + " ".join(f"{name}={_fmt(v)}" for name, v in result.values.items())
        + f"; model error {100 * result.model_error:g}%"
    )
    camera = result.camera_table()
    text = f"{head}\n{result.table()}\n" + (f"{camera}\n" if camera else "") + result.summary()
    if result.goodness is not None:
        g = result.goodness
        expectation = (
            "the scenes do not describe the images even here: a fit cannot do better, and will say it failed"
            if g.significant
            else f"a fit that lands here should show about 1 (within {g.spread:.2g})"
        )
        text += f"\nmeasure of fit at these controls: chi2/dof {g.ratio:.2f}; {expectation}"
        if g.significant:
            text += "\n" + "\n".join(g.lines()[1:])
    return text


def _fmt(value) -> str:
    if isinstance(value, list):
        return "(" + ",".join(f"{v:g}" for v in value) + ")"
    return f"{value:g}"
