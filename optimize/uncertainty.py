"""Uncertainties of the fitted controls from the curvature of the loss at the estimate, and identifiability.

From the loss linearised at the estimate (`linearize.py`: weighted residuals r, their Jacobian A by the fitted
control components, loss weights w, N residuals, p components), the classical covariance of nonlinear least
squares, plus the Monte Carlo error of the estimate itself:

    Cov(x) ≈ s² H⁻¹ + Cov_MC,     H = Σ w aᵢaⱼ (`Linearization.curvature`),
    s² = Σ w (r² − Var_MC) / (N − p),

s² measures what the target scatters by around the model (its own noise and any misfit): Var_MC, the Monte
Carlo variance of our own render of each residual, is removed from it (s² is averaged over the refinement's
later linearisations, H taken from the Jacobians of its last eight). s² H⁻¹ treats the residuals as
independent, but a pixel's three channels share their paths; the statistical term is therefore taken to
correlate within a pixel as our render's noise does, measured from the difference of its two passes
(`Linearization.statistical_covariance`). The estimate is the mean of m Gauss–Newton end points, each moved by
its linearisation's render noise; Cov_MC is that mean's covariance (`refine.mean_covariance`). After Adam alone
it is left out.

Identifiability: two components whose estimates correlate by |ρ| > 0.95 trade off against each other in these
images (albedo and β_n can, through the albedo inversion, under a single front light); a control the images do
not change with has a zero column in A. Both end in `result.warnings` with what to do about them.
"""

from __future__ import annotations

import itertools

import numpy as np

from .latents import SPECS, by_control
from .linearize import Linearization

CORRELATION_WARNING = 0.95


def component_labels(names) -> list[str]:
    labels = []
    for name in names:
        labels += [f"{name}[{'rgb'[k]}]" for k in range(3)] if SPECS[name].size == 3 else [name]
    return labels


def estimate_uncertainty(result, lin: Linearization, mc_covariance: np.ndarray | None = None) -> None:
    """Fill result.uncertainties, result.correlations and identifiability warnings (see the module docstring).
    mc_covariance: the estimate's own Monte Carlo covariance (`refine`); None leaves it out."""
    names = list(lin.values)
    A = lin.mean_jacobian
    p = A.shape[1]
    labels = component_labels(names)
    flat = np.abs(A).max(axis=0) == 0
    for label in np.array(labels)[flat]:
        result.warnings.append(f"{label} does not change the rendered images at all: it cannot be fitted from this target")
    cov = lin.statistical_covariance
    if mc_covariance is not None:
        cov = cov + mc_covariance
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    result.uncertainties = by_control(names, sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cov / np.outer(sigma, sigma)
    owners = [label.split("[")[0] for label in labels]
    for i, j in itertools.combinations(range(p), 2):
        if owners[i] == owners[j] or not np.isfinite(rho[i, j]):
            continue
        result.correlations[f"{labels[i]}/{labels[j]}"] = float(rho[i, j])
        if abs(rho[i, j]) > CORRELATION_WARNING:
            result.warnings.append(
                f"{labels[i]} and {labels[j]} trade off in these images (correlation {rho[i, j]:+.3f}): a change of "
                f"one is largely compensated by the other, and their uncertainties (±{sigma[i]:.2g}, "
                f"±{sigma[j]:.2g}) lie mostly along that trade-off. To tell them apart, add an image under another "
                "light or from another view (a back-lit one shows transmission), or fix one of them."
            )

