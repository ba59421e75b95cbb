"""Fitting the hair controls to target images: losses, reparametrisation, the fitting loop, targets, reports.

    from optimize import fit, load_target
    result = fit(load_target("targets/blonde_straight"))
    print(result.values, result.uncertainties)

Depends on warp_hair (the renderer and its gradients), never the reverse.
"""

from .fit import FitResult, FitSettings, fit
from .target import Target, load_target, make_target

__all__ = ["FitResult", "FitSettings", "Target", "fit", "load_target", "make_target"]
