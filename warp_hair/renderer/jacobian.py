"""`render_jacobian` under the path README documented before it moved to `renderer.gradients` (beside
`render_grad`, its contraction); `model.jacobian` is the BSDF's own derivatives. New code imports it from there."""

from .gradients import render_jacobian

__all__ = ["render_jacobian"]
