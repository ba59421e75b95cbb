"""Uncertainties of the fitted controls from the curvature of the loss at the estimate, and identifiability.

From the loss linearised at the estimate (`linearize.py`: residuals r, their Jacobian A by the fitted control
components, N residuals, p components), the classical standard errors of nonlinear least squares:

    Cov(x) ≈ s² (AᵀA)⁻¹,     s² = (Σ r² − Σ Var_MC) / (N − p),

where Var_MC is the Monte Carlo variance of our own render of the residual (its per-pixel standard errors),
removed so that s² measures what the target scatters by around the model (its own noise and any misfit), not
the noise of our evaluation. r and A are the means of the linearisation's two independent passes.

Identifiability: two components whose estimates correlate by |ρ| > 0.95 trade off against each other in these
images (albedo and β_n can, through the albedo inversion, under a single front light); a control the images do
not change with has a zero column in A. Both end in `result.warnings` with what to do about them.
"""

from __future__ import annotations

import itertools

import numpy as np

from .controls import SPECS, by_control
from .linearize import Linearization

CORRELATION_WARNING = 0.95


def component_labels(names) -> list[str]:
    labels = []
    for name in names:
        labels += [f"{name}[{'rgb'[k]}]" for k in range(3)] if SPECS[name].size == 3 else [name]
    return labels


def estimate_uncertainty(result, lin: Linearization) -> None:
    """Fill result.uncertainties, result.correlations and identifiability warnings (see the module docstring)."""
    names = list(lin.values)
    A, r, mc_variance = lin.mean_jacobian, lin.mean_residual, lin.mean_variance
    n, p = A.shape
    labels = component_labels(names)
    flat = np.abs(A).max(axis=0) == 0
    for label in np.array(labels)[flat]:
        result.warnings.append(f"{label} does not change the rendered images at all: it cannot be fitted from this target")
    s2 = max(float(r @ r - mc_variance.sum()), 0.1 * float(r @ r)) / max(n - p, 1)
    cov = s2 * np.linalg.pinv(A.T @ A)
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
                f"{labels[i]} and {labels[j]} are not separately identifiable from these images (correlation "
                f"{rho[i, j]:+.3f}): a change of one is compensated by the other. Add an image under another light "
                "(a back-lit one shows transmission) or fix one of them."
            )

