"""What the fit solves beside the look: one object for its nuisance unknowns, asked the same questions by every
stage (the descent's loss, fit.py; the linearisation, linearize.py; the uncertainties and the report).

The unknowns today are the gains every render is multiplied by before it meets the target:

- a photo's exposures and white balance (camera.py: `gains` and `white_balance` in target.toml), solved in closed
  form for each set of renders and never stepped (variable projection), their columns projected out of the
  linearisation so that steps and σ are those of the loss minimised over them;
- the `exposure` control, one gain on every image, a fitted control like the look's (latents.py), whose gradient
  flows through the loss; 1 where it is not fitted.

A target has one or the other, never both (`check`). How the strands lie, the other nuisance of a photographed
swatch, is not a gain: the fit averages over its stated prior through the realisations it renders and estimates it
at its end (arrangement.py).

    nuisance = Nuisance(target)
    gains, solved = nuisance.gains(gain, pairs, references, masks, loss, pool, scales)   # per image, (3,) or scalar
    projection = nuisance.projection(solved, targets, weights, jacobians, counts, gain_columns)   # None: nothing
    nuisance.report(lin, hair_covariance, model_error, shift)   # their values and σ, None where there are none
"""

from __future__ import annotations

from dataclasses import dataclass

from . import camera
from .latents import EXPOSURE


@dataclass(frozen=True)
class Nuisance:
    target: object

    @property
    def solved(self) -> bool:
        """Whether the gains are solved in closed form for each set of renders (a photo's), not fitted."""
        return camera.fitted(self.target)

    def check(self, names) -> None:
        """A photo's solved gains and the exposure control would be two gains on every image."""
        if self.solved and EXPOSURE in names:
            raise ValueError(
                f"{self.target.name}: its gains are fitted already (gains = {self.target.gains!r}, camera.py); "
                "exposure would be a second gain on every image: leave it out of the controls"
            )

    def gains(self, gain, pairs, references, masks, loss: str, pool: int, scales) -> tuple:
        """(per image, the factor its renders are multiplied by before the loss; the solved camera.Gains or None).
        `gain`: the exposure control's value (a torch scalar in the descent, whose gradient flows; a float in the
        linearisation), used where the gains are not solved; `pairs`: per image, two independent renders of it."""
        if not self.solved:
            return [gain] * len(pairs), None
        solved = camera.gains_for(self.target, pairs, references, masks, loss, pool, scales)
        return list(solved.per_channel), solved

    def projection(self, solved, targets, weights, jacobians, image_residuals, gain_columns):
        """The loss minimised over solved gains, for the linearisation (camera.Projection); None for a gain that
        is a fitted control or 1. The gains' columns are ∂r/∂log g = ω G I, which at the gains' optimum is the
        weighted target t up to the residual.

        Taken from t, the projected residual P⊥(m − t) = P⊥m is linear in our render, a model that steps well from
        afar, and the projection is free of our render noise. But the target's own noise ε is then in both the
        columns and the residual: Cᵀ W r holds −εᵀ W ε, whose mean is not zero, and the gradient at the truth leans
        along Aᵀ W t by the target's noise energy over its energy, towards a darker hair behind brighter gains
        (docs/acceptance.md, "Photographs": red albedo 0.09 low one step from the truth on chestnut_straight with
        free gains). Taken from a render independent of the target and of both passes (`gain_columns`: the mean
        of earlier linearisations' renders, near these controls) the lean is gone. Its linear model keeps P⊥t,
        which turns with the hair, so refine.py uses it only for its later steps, near the optimum, and holds one
        set of columns for all of them: along the albedo–gain valley the projected curvature is so small that each
        step's own columns, noisy, would change it from step to step (measured: the steps then scattered twice as
        far)."""
        if solved is None:
            return None
        m = targets if gain_columns is None else gain_columns
        return camera.Projection(
            solved,
            camera.columns(self.target, m, image_residuals),
            weights,
            jacobians.mean(axis=0),
            camera.labels(self.target),
        )

    def report(
        self, projection, hair_covariance, scatter: float, model_error: float, shift=None, realisation=None
    ) -> dict | None:
        """The solved gains' values and σ (camera.report) for params.json and the printed table; None where the
        gains are not solved (a fitted exposure is a control, reported with the look)."""
        if projection is None:
            return None
        return camera.report(projection, self.target, hair_covariance, scatter, model_error, shift, realisation)
