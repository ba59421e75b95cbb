"""Which light a vertex's shadow ray goes to: one emitter per vertex, chosen with a probability proportional to the
most irradiance it gives a surface, over the surface's orientations, where Mitsuba 3 (and pbrt-v4's BVH light
sampler, for lights at infinity) chooses uniformly.

A vertex traces one shadow ray whatever the number of lights and divides what it finds by the chosen light's
probability, so the estimate is unbiased for any choice that gives every light that sends something a probability
above 0; the choice sets the noise. A directional light's weight is its irradiance E (what the scene file states:
on a surface facing it); an environment's is the irradiance on a surface turned to where it gives most
(`envmap.peak_irradiance`): π L for a constant sky, about a sun's E plus the sky around it for a map with a sun.
Each is the mean of its three channels.

Why this and not power, as pbrt-v4's `PowerLightSampler` (the flux into the scene's bounding sphere: E π r² against
4π L̄ π r² for a sky), nor the uniform choice: measured (docs/benchmarks.md, "Which light a shadow ray goes to"),
a constant sky weighted by its power gave the standard swatch more noise than the uniform choice, and weighted
by π L 1.5–1.9× less than uniform on both swatches: a light sample toward a constant sky is drawn uniformly over
the sphere and mostly lands where the hair's lobes are not or where other fibers block it, while the BSDF's own
samples, weighted against it by MIS (`integrator.escaped`), find that light well. A map with a sun is the other
case: its light samples find the sun, and weighed by its mean radiance (π L̄, a quarter of a sun's share here) it
had 1.3× the uniform choice's noise; by its peak irradiance it has the uniform choice's.

A scene whose lights are all black is given a uniform choice (there is nothing to estimate, and the table must
still sum to 1). A scene with one light draws the one number it always drew and chooses that light.

    cdf = selection_cdf(directional, environment)   # host: the emitters in SceneData's order (directional, env)
    k, p = choose_light(cdf, u)                     # kernel: emitter k, chosen with probability p
    p = light_probability(cdf, k)                   # kernel: what choose_light gives k (MIS at an escaped ray)
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..scene import DirectionalLight, EnvironmentLight
from .envmap import peak_irradiance

wp.set_module_options({"enable_backward": False, "optimization_level": 3})


def light_weight(light) -> float:
    """What `light` is chosen in proportion to (the module docstring says what and why)."""
    if isinstance(light, DirectionalLight):
        return float(np.mean(light.irradiance))
    if isinstance(light, EnvironmentLight):
        return peak_irradiance(light.radiance, light.image)
    raise TypeError(f"not a light: {light!r}")


def selection_cdf(directional: list, environment) -> np.ndarray:
    """float32 cumulative probabilities of the emitters in the kernels' order (the directional lights, then the
    environment if any): entry k is the probability of choosing one of emitters 0..k. The last emitter with any
    light ends at exactly 1, so that no u ∈ [0, 1) chooses a black one after it. Uniform where every light is black;
    empty for a scene without lights."""
    lights = [*directional, *([environment] if environment is not None else [])]
    weight = np.array([light_weight(light) for light in lights], dtype=np.float64)
    if weight.size == 0:
        return np.zeros(0, dtype=np.float32)
    if not weight.sum() > 0.0:
        weight = np.ones_like(weight)
    cdf = np.cumsum(weight / weight.sum())
    cdf[int(np.flatnonzero(weight > 0.0)[-1]) :] = 1.0
    return cdf.astype(np.float32)


@wp.func
def light_probability(cdf: wp.array(dtype=float), k: int):
    """The probability that `choose_light` chooses emitter k: the width of its step of the CDF."""
    below = float(0.0)
    if k > 0:
        below = cdf[k - 1]
    return cdf[k] - below


@wp.func
def choose_light(cdf: wp.array(dtype=float), u: float):
    """(k, its probability): the first emitter whose cumulative probability exceeds u ∈ [0, 1). A black emitter's
    step has no width, so no u chooses it."""
    k = int(0)
    while u >= cdf[k]:
        k += 1
    return k, light_probability(cdf, k)
