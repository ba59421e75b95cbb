"""The derivative checks' shared parts (tests/test_bsdf_grad.py, tests/test_bsdf_jacobian.py): random materials
and configurations, finite differences of the float64 reference model, and the natural scale of each control.
"""

import math

import numpy as np

import warp_hair as wh
from warp_hair.controls import COLOUR_INPUTS
from warp_hair.model.params import lobe_variances, logistic_scale, longitudinal_variance

from . import reference_model as ref
from .sphere import random_directions

RTOL = 1e-4
ATOL = 1e-5
UNDERFLOW = 1e-30
FD_STEP = 1e-5
COLOUR_MODES = COLOUR_INPUTS

# The smallest step scale per control: σ_a, melanin and α may be 0.
STEP_FLOOR = {"sigma_a": 1e-2, "eumelanin": 1e-2, "pheomelanin": 1e-2, "alpha": 1.0}


def _float32(value):
    return [float(np.float32(v)) for v in value] if isinstance(value, list) else float(np.float32(value))


def random_controls(rng, mode: str) -> dict:
    if mode == "albedo":
        colour = {"albedo": list(rng.uniform(0.02, 0.99, 3))}
    elif mode == "sigma_a":
        colour = {"sigma_a": list(rng.uniform(0.0, 4.0, 3))}
    else:
        colour = {"eumelanin": rng.uniform(0.0, 8.0), "pheomelanin": rng.uniform(0.0, 3.0)}
    controls = dict(
        colour,
        beta_m=rng.uniform(0.02, 1.0),
        beta_n=rng.uniform(0.02, 1.0),
        alpha=rng.uniform(-25.0, 25.0),
        eta=rng.uniform(1.05, 2.5),
        r_roughness_scale=math.exp(rng.uniform(math.log(0.1), math.log(10.0))),
    )
    return {name: _float32(value) for name, value in controls.items()}


def configurations(rng, params, n):
    """(wo, wi, h) in float32; the second half of wi importance-sampled from the material itself."""
    wo = random_directions(rng, n).astype(np.float32)
    wi = random_directions(rng, n).astype(np.float32)
    h = rng.uniform(-0.999, 0.999, n).astype(np.float32)
    half = n // 2
    wi[half:] = wh.bsdf.sample(params, wo[half:], h[half:], rng.random((n - half, 3)))[0]
    return wo, wi, h


def control_entries(controls: dict):
    """(name, component) of every scalar the material's derivatives are taken for; component None for scalars."""
    entries = []
    for name, value in controls.items():
        entries += [(name, k) for k in range(3)] if isinstance(value, list) else [(name, None)]
    return entries


def shifted(controls: dict, name: str, component, step: float) -> dict:
    out = dict(controls)
    if component is None:
        out[name] = controls[name] + step
    else:
        out[name] = list(controls[name])
        out[name][component] += step
    return out


def lobe_factors(controls, wo, wi, h):
    """G (N, 4) = M_p N_p per lobe, and F (N, 4, 4): A_p per channel of S, then the lobe probability."""
    MN, A = ref.lobe_terms(ref.coefficients(controls), wo, wi, h)
    return MN, np.concatenate([A, ref.lobe_probs(A)[:, :, None]], axis=2)


def reference_derivative(controls, name, component, wo, wi, h):
    """(d, terms, out), each (N, 4) over (S_r, S_g, S_b, pdf): the derivative, Σ of its terms' magnitudes, the
    output."""
    value = controls[name] if component is None else controls[name][component]
    step = FD_STEP * max(abs(value), STEP_FLOOR.get(name, 0.0))
    at = {j: lobe_factors(shifted(controls, name, component, j * step), wo, wi, h) for j in (-2, -1, 1, 2)}

    def five_point(i):
        return (at[-2][i] - 8.0 * at[-1][i] + 8.0 * at[1][i] - at[2][i]) / (12.0 * step)

    G, F = lobe_factors(controls, wo, wi, h)
    dG, dF = five_point(0)[:, :, None], five_point(1)
    G = G[:, :, None]
    d = (dG * F + G * dF).sum(axis=1)
    terms = (np.abs(dG * F) + np.abs(G * dF)).sum(axis=1)
    return d, terms, (G * F).sum(axis=1)


def _log_slope(mapping, x):
    return abs(math.log(mapping(x * (1 + 1e-6))) - math.log(mapping(x * (1 - 1e-6)))) / (2e-6 * x)


def natural_scale(controls: dict, name: str) -> float:
    """ν_k: log-change of the lobes per unit of the control, the size of the parts its derivative sums.

    β_m, r_roughness_scale: d log v / dθ (v the longitudinal variance they set). β_n: d log s / dβ_n.
    α (degrees): the largest rotation of θ_o per degree (4α on TRT) over the narrowest lobe's width √v.
    η: the azimuthal centres move O(1) per unit η, over the logistic width s; Fresnel and absorption O(1).
    Colours: 1 per unit of albedo, σ_a or melanin.
    """
    if name == "beta_m":
        return _log_slope(longitudinal_variance, controls["beta_m"])
    if name == "r_roughness_scale":
        return 1.0 / controls["r_roughness_scale"]
    if name == "beta_n":
        return _log_slope(logistic_scale, controls["beta_n"])
    if name == "alpha":
        v = lobe_variances(controls["beta_m"], controls["r_roughness_scale"])
        return 4.0 * math.radians(1.0) / math.sqrt(v.min())
    if name == "eta":
        return 1.0 + 1.0 / logistic_scale(controls["beta_n"])
    return 1.0
