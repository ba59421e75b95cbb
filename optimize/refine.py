"""Gauss–Newton refinement of a fit: a few Levenberg–Marquardt steps on the linearised loss after Adam.

Adam's steps are sized by its learning rate, not by the loss's curvature, and where two controls trade off
(albedo against β_n through the albedo inversion) the loss has a long shallow valley that its last, small
steps cross slowly: measured before this stage existed, blonde_straight's fit ended 0.038 off in red albedo and
fur_patch's 0.17 off in albedo and β_n, while the Gauss–Newton standard errors there were under 0.002. The loss
is a sum of squared residuals (`linearize.py`), so the Gauss–Newton step of the latents z solves

    (Aᵀ A + λ diag(Aᵀ A)) δz = −Aᵀ r,     A = ∂r/∂x · ∂x/∂z,

in the same unconstrained latents Adam moves (every step stays inside every control's range), with Aᵀ r from
independent passes and A, r weighted as the loss weighs them. A step is kept when it lowers the loss as
estimated by the trapezoid rule on the slopes along it, ½ (∇ℓ(z) + ∇ℓ(z + δz))·δz (exact for a quadratic).
Gradients are unbiased and their noise is modest; loss values are not: each carries our render's Monte Carlo
variance, which grows with the radiance, so that comparing losses (even with common random numbers) undid
steps on fur_patch that landed on the truth, and the noise-free `misfit` of independent passes scattered by as
much as the steps changed it. λ then shrinks, else it grows and the step is retried from the same
linearisation (all steps render with the same seeds). L2 and relative L2 are sums of squares as they stand; the L1
loss is not, and is not refined.
"""

from __future__ import annotations

import numpy as np
import torch

from .linearize import Linearization, linearize

LAMBDA_START = 1e-3
LAMBDA_DOWN, LAMBDA_UP = 1 / 3, 5.0
LAMBDA_MAX = 1e4  # a step this damped moves nothing: stop
REFINABLE_LOSSES = ("l2", "rel_l2")


def _flat(latents) -> torch.Tensor:
    return torch.cat([t.detach().reshape(-1) for t in latents.tensors.values()])


def _split(latents, z: torch.Tensor) -> dict:
    out, k = {}, 0
    for name, t in latents.tensors.items():
        out[name] = z[k:k + t.numel()].reshape(t.shape)
        k += t.numel()
    return out


def _plain(values: dict) -> dict:
    return {name: (v.detach().tolist() if v.dim() else float(v.detach())) for name, v in values.items()}


def refine(target, latents, settings, spp: int, seed: int, steps: int, on_step=None):
    """(values, Linearization at them, [per-step {"values", "loss", "misfit", "change", "accepted"}]).

    `latents` is the fit's (its tensors and `values_from`); each kept step is stored in it, so that after a
    KeyboardInterrupt it holds the best values so far. `on_step(record)` is called after each step.
    """
    z = _flat(latents).to(torch.float64)
    names = list(latents.tensors)

    def controls(z_flat):
        values = latents.values_from(_split(latents, z_flat))
        return torch.cat([values[name].reshape(-1) for name in names])

    def linearized(z_flat) -> Linearization:
        return linearize(target, _plain(latents.values_from(_split(latents, z_flat))), settings, spp, seed,
                         threads=settings.threads)

    def slope(lin_at, z_at):
        """(∂x/∂z, ½ ∂loss/∂z) at z_at."""
        dx_dz = torch.autograd.functional.jacobian(controls, z_at).numpy()
        return dx_dz, dx_dz.T @ lin_at.gradient

    lin = linearized(z)
    dx_dz, g = slope(lin, z)
    records = []
    damping = LAMBDA_START
    for _ in range(steps):
        a = (lin.mean_jacobian @ dx_dz) * np.sqrt(lin.loss_weights)[:, None]
        h = a.T @ a
        step = -np.linalg.solve(h + damping * np.diag(np.diag(h)) + 1e-12 * np.eye(len(g)), g)
        z_new = z + torch.from_numpy(step)
        lin_new = linearized(z_new)
        dx_dz_new, g_new = slope(lin_new, z_new)
        # The change of ½·loss along the step by the trapezoid rule on its slopes at both ends: exact for a
        # quadratic, and built from unbiased gradients instead of noisy loss values.
        change = 0.5 * float(g @ step + g_new @ step)
        accepted = bool(np.isfinite(change) and change < 0)
        if accepted:
            z, lin, dx_dz, g = z_new, lin_new, dx_dz_new, g_new
            _store(latents, z)
            damping = max(damping * LAMBDA_DOWN, 1e-9)
        else:
            damping *= LAMBDA_UP
        records.append({"values": lin_new.values, "loss": lin_new.loss, "misfit": lin_new.misfit,
                        "change": 2.0 * change, "accepted": accepted})
        if on_step is not None:
            on_step(records[-1])
        if damping > LAMBDA_MAX:
            break
    return lin.values, lin, records


def _store(latents, z):
    for name, t in _split(latents, z).items():
        latents.tensors[name].data.copy_(t)
