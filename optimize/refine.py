"""Gauss–Newton refinement of a fit: a few Levenberg–Marquardt steps on the linearised loss after Adam.

Adam's steps are sized by its learning rate, not by the loss's curvature, and where two controls trade off
(albedo against β_n through the albedo inversion) the loss has a long shallow valley that its last, small
steps cross slowly. The loss is a sum of squared residuals (`linearize.py`), so the Gauss–Newton step solves

    (H + λ diag(H)) δx = −Aᵀ r,     H ≈ Aᵀ A,  A = ∂r/∂x,

A and H from the Jacobians of the last JACOBIAN_WINDOW linearisations (`Linearization.earlier_jacobians`:
each residual pass meets the mean of the Jacobians but its own, and H is unbiased), A and r weighted as the loss
weighs them; in the controls themselves (not Adam's latents: in log σ_a a high albedo's image is so curved that
a step overshoots), and shortened where it would go more than half way to a bound.

A step is kept only when it does not make the fit worse beyond what our render noise can hide: the misfit at its end
(`Linearization.misfit`, Σ w r₁ r₂ of two independent passes, unbiased for the loss without our noise) may exceed
the misfit where it started by no more than MISFIT_Z standard errors of their difference
(`Linearization.misfit_variance` of both). A slope test (trapezoid rule on the gradients at both ends) kept steps
whose loss rose 0.041 → 0.089 → 0.208 on a groom (issue 42): the loss is no quadratic there, and a linear model with
a noisy curvature can be confident of anything. A step that fails is undone, λ grows and the step is retried,
shorter, from the same linearisation (Levenberg–Marquardt); a kept step shrinks λ. At the optimum the misfit's
change is noise and about 98% of such steps are kept (the one-sided 2σ quantile).

Why not common random numbers: the kept points are averaged (below), and they must carry independent noise
for their mean to shed it; rendering the start again with the candidate's seeds would cost a second render per
step. Independent seeds with the noise counted cost nothing more.

The refinement also remembers the best linearisation it saw (the lowest misfit, the start included: Adam's end
point) and, should the averaged estimate fit worse than that one beyond noise (BEST_Z standard errors, for
the best of many noisy values is low by chance), returns that point instead and says so: the refinement never
leaves the fit worse than Adam left it.

Every linearisation renders with fresh seeds, so each step's end point carries that render's own noise (with
common seeds every step would converge to the same noisy point). The result is the mean of the end points of
steps taken from settled points, which scatter around the optimum as Adam's last iterates do; `mean_covariance`
is its Monte Carlo error. A point is settled when the gradient there is zero within our render noise (its χ²
against `Linearization.gradient_covariance` below the SETTLED quantile): a step from it lands where a step from
the optimum would, up to that noise, and so does every step after; Adam usually leaves the fit a few steps short
of it. (Pooling no Jacobian from before a far step, so that none from Adam's end point leans the settled steps,
was tried: a single linearisation's curvature sent fur_patch's second step from albedo 0.55 to 0.38 and its
refinement into a region it took 20 steps to leave.) A refinement of `steps` planned steps averages
`averaged_points(steps)` end points (the precision those steps were sized for: settings.refine_steps,
identify.py) and counts its points as settled by force where the later half of its steps begins, so it takes no
more steps than planned unless its points drift: from a start far from the optimum, in a curved valley, the
steps can creep, and while the averaged points still follow a trend (`drift_statistic`), the refinement takes
more steps, up to MAX_EXTENSION times as many, and says so if they never settle.

L2 and relative L2 are sums of squares as they stand; the L1 loss is not, and is not refined.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from .latents import by_control, component_bounds, flat_values
from .linearize import Linearization, linearize
from .uncertainty import component_labels

LAMBDA_START = 1e-3
LAMBDA_DOWN, LAMBDA_UP = 1 / 3, 5.0
LAMBDA_MAX = 1e4  # a step this damped moves nothing: stop
SEED_STRIDE = 7919  # each linearisation renders with its own seeds
JACOBIAN_WINDOW = 8  # linearisations whose Jacobians are pooled
EMPIRICAL_POINTS = 4  # end points needed before their own scatter is trusted to tell their noise
REFINABLE_LOSSES = ("l2", "rel_l2")
MISFIT_Z = 2.0  # a step whose misfit rises by more than this many standard errors made the fit worse
# The result gives way to the best point seen only this many standard errors apart: the lowest of n noisy
# misfits lies about 1.8 (n = 16) to 2.2 (n = 48) of theirs below their mean, so at 2 an estimate at the optimum
# would give way in one fit in six; at 3.5 in under one in two hundred.
BEST_Z = 3.5
DRIFT_T = 3.0  # a trend in the averaged points this many standard errors strong means they still move
DRIFT_POINTS = 5  # fewer averaged points do not tell a trend (a t statistic with 3 degrees of freedom or more)
MAX_EXTENSION = 3  # a refinement whose points still move runs on, up to this many times its planned steps
# A point is settled when its gradient's χ² against its noise is below this quantile of the χ² distribution (one
# optimum in a hundred is taken for unsettled, and costs a step; the gradient's noise leaves out the earlier
# Jacobians', so the test errs that way).
SETTLED = 0.99


def inside(x: np.ndarray, step: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The step shortened, if it must be, so that no component goes more than half its way to a bound of its
    open interval: a step that would leave a control's range is a linear model trusted too far."""
    room = np.where(step < 0, x - lo, hi - x)
    with np.errstate(divide="ignore", invalid="ignore"):
        limits = np.where(np.abs(step) > 0.5 * room, 0.5 * room / np.abs(step), 1.0)
    return step * float(np.min(limits, initial=1.0))


@dataclass(frozen=True)
class GaussNewtonStep:
    """One Levenberg–Marquardt step as it was tried: the linearisation at its end point (values, loss, misfit),
    the change of the misfit from where it started with that change's standard error, and whether it was kept
    (`change` ≤ MISFIT_Z · `noise`)."""

    values: dict
    loss: float
    misfit: float
    change: float
    accepted: bool
    noise: float = 0.0


@dataclass(frozen=True)
class Refinement:
    """What the refinement leaves: the refined controls, the linearisation at them and the Monte Carlo
    covariance of their mean (None when fewer than two steps were kept, or when interrupted), every step tried
    and its warnings. `interrupted`: Ctrl-C stopped it; `values` are then the last kept step's (the start's if
    none was kept) and there is no linearisation at them."""

    values: dict
    linearization: Linearization | None
    mc_covariance: np.ndarray | None
    steps: tuple[GaussNewtonStep, ...]
    warnings: tuple[str, ...] = ()
    interrupted: bool = False
    # The misfit (and its standard error) where the refinement started, at Adam's estimate, and at its result.
    start_misfit: tuple[float, float] | None = None
    end_misfit: tuple[float, float] | None = None


class GaussNewton:
    """The refinement as a run: `step()` takes one Levenberg–Marquardt step, `done` says when to stop (after
    `steps` steps, or more while the averaged points still move, up to MAX_EXTENSION × steps; or when the
    damping has grown so large that a step moves nothing), `result()` averages the later kept points and
    linearises there.

    start: the controls to refine from ({name: float or list of 3}); constructing the run linearises there.
    `kept_values` is the last kept step's end point (the start before any): what a fit interrupted during the
    refinement returns. Each linearisation renders with its own seeds (seed + SEED_STRIDE × its index); `scenes`:
    the target's prepared scenes (`linearize`), or a function of that seed giving them (a fit over random
    realisations of the fibers draws a new pair of realisations per linearisation: optimize/realisations.py).
    """

    def __init__(self, target, start: dict, settings, spp: int, seed: int, steps: int, scenes=None):
        self.target, self.settings, self.spp, self.seed, self.scenes = target, settings, spp, seed, scenes
        self.names = list(start)
        self.lo, self.hi = component_bounds(self.names)
        self.planned = steps
        self.needed = averaged_points(steps)
        self.settled_by = steps - self.needed  # the linearisation from which the planned steps' rule averaged
        self.k = 0
        self.settled = False  # whether a point has been found settled: every linearisation since is at one
        self.averaging = False  # whether the current linearisation's step end point counts (`averaged`)
        self.x = flat_values(start)
        self.kept_values = start
        # One linearisation's Jacobian is noisy, and so then are the curvature (where it comes out too small, a
        # step overshoots and the steps oscillate around the optimum) and the gradient. Those of the last few
        # linearisations together are steadier, and unlike all of them they forget the start's, whose curvature
        # far from the optimum would keep the steps short.
        self.jacobians = []  # each linearisation's pair, in order
        self.settled_models = []  # a photo's weighted model of each settled linearisation (`_gain_columns`)
        self.kept, self.scatters = [], []  # the kept end points and their linearisations' scatter estimates
        self.averaged, self.averaged_scatters = [], []  # the kept end points of steps from settled points
        self.steps: list[GaussNewtonStep] = []
        self.damping = LAMBDA_START
        self.lin = self._with_earlier(self._linearized(self.x, 0))
        self.start = self.best = self.lin  # Adam's end point; the lowest misfit seen

    def _linearized(self, x_at, k) -> Linearization:
        return linearize(
            self.target,
            by_control(self.names, x_at),
            self.settings,
            self.spp,
            self.seed + SEED_STRIDE * k,
            threads=self.settings.threads,
            scenes=self.scenes(self.seed + SEED_STRIDE * k) if callable(self.scenes) else self.scenes,
            gain_columns=self._gain_columns(),
        )

    def _gain_columns(self):
        """For a photo's gains, once a point has settled, the mean render of the settled linearisations before this
        one (the last JACOBIAN_WINDOW − 1), instead of the target (nuisance.Nuisance.projection): near the optimum
        it removes the lean that the target's noise gives the steps, where from afar the target's columns step more
        surely. None before, and for the first settled linearisation, which has no settled render before it."""
        earlier = [m for m in self.settled_models[-(JACOBIAN_WINDOW - 1) :] if m is not None]
        return np.mean(earlier, axis=0) if self.settled and earlier else None

    def _with_earlier(self, lin_at: Linearization) -> Linearization:
        """lin_at with the Jacobians of the JACOBIAN_WINDOW − 1 linearisations before it."""
        earlier = self.jacobians[-(JACOBIAN_WINDOW - 1) :]
        self.jacobians.append(lin_at.jacobians)
        if not earlier:
            return lin_at
        return dataclasses.replace(lin_at, earlier_jacobians=np.concatenate(earlier), curvature=None)

    @property
    def done(self) -> bool:
        """After the planned number of averaged points (or the planned steps, should many be undone), unless those
        points still drift; after MAX_EXTENSION × the planned steps, or damping that moves nothing, in any case."""
        if self.damping > LAMBDA_MAX or self.k >= MAX_EXTENSION * self.planned:
            return True
        enough = 0 < self.needed <= len(self.averaged) or self.k >= self.planned
        return enough and not drifting(self._averaged_points())

    def _settles(self) -> bool:
        """Whether the current point is settled (the module docstring), or the planned steps' rule would average
        from here on."""
        if self.k - 1 >= self.settled_by:
            return True
        lin = self.lin
        chi2 = float(lin.gradient @ np.linalg.lstsq(lin.gradient_covariance, lin.gradient, rcond=1e-12)[0])
        return np.isfinite(chi2) and chi2 <= chi2_quantile(SETTLED, len(self.x))

    def _settle(self) -> None:
        """From here on every linearisation is at a settled point: a photo's gain columns come from settled
        linearisations only, and this point's step counts, unless it is a photo's whose gains still took the
        target's columns."""
        self.settled = True
        self.settled_models = [self.lin.model]
        self.averaging = self.lin.model is None

    def step(self) -> GaussNewtonStep:
        self.k += 1
        if not self.settled and self._settles():
            self._settle()
        lin, x, counts = self.lin, self.x, self.averaging
        h = lin.curvature
        damped = h + self.damping * np.diag(np.diag(h)) + 1e-12 * np.eye(len(x))
        step = inside(x, -np.linalg.solve(damped, lin.gradient), self.lo, self.hi)
        lin_new = self._with_earlier(self._linearized(x + step, self.k))
        # Against where this step starts. (Also against where the refinement started, whichever fitted better, was
        # tried: an anchor whose misfit came out low by chance then undid step after step, and on a photo over random
        # realisations the refinement stuck at albedo 0.22 for a true 0.45. A drift into a worse region is caught at
        # the end instead: `result` gives way to the best point seen.)
        change, noise = misfit_change(lin, lin_new)
        accepted = bool(np.isfinite(change) and change <= MISFIT_Z * noise)
        if accepted:
            self.x, self.lin = x + step, lin_new
            self.kept.append(self.x)
            self.scatters.append(lin_new.scatter_estimate)
            if counts:
                self.averaged.append(self.x)
                self.averaged_scatters.append(lin_new.scatter_estimate)
            if self.settled:
                self.settled_models.append(lin_new.model)
                self.averaging = True
            self.kept_values = lin_new.values
            self.damping = max(self.damping * LAMBDA_DOWN, 1e-9)
        else:
            self.damping *= LAMBDA_UP
        if np.isfinite(lin_new.misfit) and lin_new.misfit < self.best.misfit:
            self.best = lin_new
        record = GaussNewtonStep(
            values=lin_new.values,
            loss=lin_new.loss,
            misfit=lin_new.misfit,
            change=change,
            accepted=accepted,
            noise=noise,
        )
        self.steps.append(record)
        return record

    def _averaged_points(self, scatters: bool = False) -> list:
        """The end points averaged into the estimate: the last `needed` of those stepped from settled points; the
        later half of all kept points where none was (a refinement stopped before any point settled). `scatters`:
        their linearisations' scatter estimates instead."""
        points, fallback = (self.averaged_scatters, self.scatters) if scatters else (self.averaged, self.kept)
        return points[-self.needed :] if self.averaged and self.needed else _later(fallback)

    def result(self) -> Refinement:
        """The mean of the end points of the steps from settled points, linearised there (see the module
        docstring); the best point seen instead, should that mean fit worse than it beyond noise."""
        # Each linearisation's own render noise moves its step's end point; the kept points from settled ones
        # scatter around the optimum, and their mean scatters less.
        averaged = self._averaged_points()
        scatters = self._averaged_points(scatters=True)
        notes = () if not drifting(averaged) else (_unsettled(averaged, self.k, self.names),)
        if len(self.kept) < 2:
            final, mc = self._best_of(self.lin), None
        else:
            final = self._with_earlier(self._linearized(np.mean(averaged, axis=0), self.k + 1))
            # One linearisation's scatter estimate is noisy where our render is much noisier than the target.
            final = dataclasses.replace(final, scatter=float(np.mean([*scatters, final.scatter_estimate])))
            mc = mean_covariance(averaged, final)
            best = self._best_of(final)
            if best is not final:
                change, noise = misfit_change(best, final)
                notes += (
                    f"the mean of the Gauss-Newton steps' end points fitted worse than the best point they "
                    f"visited (misfit {final.misfit:.4g} against {best.misfit:.4g}, {change / noise:.1f} standard "
                    "errors apart): the result is that point, with its own render noise",
                )
                final, mc = best, best.step_covariance
        self.kept_values = final.values
        return Refinement(
            final.values,
            final,
            mc,
            tuple(self.steps),
            notes,
            start_misfit=(self.start.misfit, float(np.sqrt(max(self.start.misfit_variance, 0.0)))),
            end_misfit=(final.misfit, float(np.sqrt(max(final.misfit_variance, 0.0)))),
        )

    def _best_of(self, lin: Linearization) -> Linearization:
        """lin, unless the best linearisation seen fits better than it beyond noise (BEST_Z standard errors)."""
        if self.best is lin:
            return lin
        change, noise = misfit_change(self.best, lin)
        return self.best if not np.isfinite(lin.misfit) or change > BEST_Z * noise else lin


def misfit_change(before: Linearization, after: Linearization) -> tuple[float, float]:
    """The misfit's change from `before` to `after` and its standard error from both renders' noise (their
    seeds are independent, so the variances add)."""
    noise = float(np.sqrt(max(before.misfit_variance + after.misfit_variance, 0.0)))
    return after.misfit - before.misfit, max(noise, 1e-300)


def _unsettled(points: list, steps: int, names) -> str:
    """The warning for averaged points that still move: which component moves most, and by how much."""
    worst = int(np.argmax(drift_statistic(points)))
    moved = float(np.ptp(np.array(points)[:, worst]))
    return (
        f"the Gauss-Newton steps had not settled after {steps} steps ({component_labels(names)[worst]} still "
        f"moving, by {moved:.3g} over the last {len(points)}): the estimate may be off by more than its "
        "uncertainty; fit again from this result (--init) or with more steps (--refine)"
    )


def drift_statistic(points: list) -> np.ndarray:
    """Per component, |slope| / its standard error of a straight line through the points in their order, the
    error from their scatter about the line. (Not from the steps' render noise, `step_covariance`: consecutive
    steps share pooled Jacobians, so their end points scatter less than independent steps would, and a trend
    that stands out clearly from their scatter can still be within that noise.)"""
    y = np.array(points)
    m = len(y)
    i = np.arange(m) - (m - 1) / 2
    sxx = float(i @ i)
    slope = i @ (y - y.mean(axis=0)) / sxx
    residual = y - y.mean(axis=0) - np.outer(i, slope)
    variance = (residual**2).sum(axis=0) / max(m - 2, 1)
    return np.abs(slope) / np.sqrt(np.maximum(variance, 1e-300) / sxx)


def drifting(points: list) -> bool:
    """Whether the points averaged into the estimate still move along a trend (a curved valley that the steps
    creep along, from a start far from the optimum): their mean would then lag behind the optimum."""
    return len(points) >= DRIFT_POINTS and bool(np.max(drift_statistic(points)) > DRIFT_T)


def _later(kept: list) -> list:
    """The later half of the kept steps after the first: the earlier ones may still be on their way in."""
    after_first = kept[1:]
    return after_first[-((len(after_first) + 1) // 2) :]


def chi2_quantile(q: float, dof: int) -> float:
    """The q quantile of the χ² distribution with `dof` degrees of freedom, by Wilson and Hilferty's cube-root
    normal approximation (within 1% from 1 degree of freedom at q = 0.99; exact enough for a threshold)."""
    z = NormalDist().inv_cdf(q)
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


def averaged_points(steps: int) -> int:
    """How many end points a refinement of `steps` steps averages into its estimate, every step kept."""
    return len(_later(list(range(steps))))


def mean_covariance(points: list, lin: Linearization) -> np.ndarray:
    """The Monte Carlo covariance of the mean of m step end points that scatter by their renders' noise:
    `step_covariance` / m, scaled up by how much more the points themselves scatter (once there are enough of them
    to tell), since `step_covariance` leaves the Jacobian's noise out."""
    m = len(points)
    model = lin.step_covariance / m
    if m >= EMPIRICAL_POINTS:
        observed = np.var(np.array(points), axis=0, ddof=1) / m
        model = model * max(1.0, float(np.mean(observed / np.maximum(np.diag(model), 1e-30))))
    return model
