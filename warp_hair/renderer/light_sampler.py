"""Which light a vertex's shadow ray goes to: one emitter per vertex, chosen with a probability proportional to
what its light samples are for, where Mitsuba 3 (and pbrt-v4's BVH light sampler, for lights at infinity) chooses
uniformly.

A vertex traces one shadow ray whatever the number of lights and divides what it finds by the chosen light's
probability, so the estimate is unbiased for any choice that gives every light the BSDF's samples cannot reach a
probability above 0; the choice sets the noise. A directional light's weight is its irradiance E (what the scene
file states: on a surface facing it). An environment's is the most irradiance its radiance above the least it
sends anywhere gives a surface, over the surface's orientations (`envmap.peak_irradiance`): about a sun's E for a
map with a sun, nothing for a constant sky. Each is the mean of its three channels.

Why the environment's uniform part counts for nothing: the BSDF's own samples find it. The hair BSDF is sampled
exactly (its weight S/pdf is 1 in every channel where nothing is absorbed, docs/MODEL.md) and the card by its
cosine, so under a uniform sky a BSDF sample's estimate varies only with what blocks it, and its escaped ray takes
the sky whole (MIS weight 1 when the sky is never light-sampled, `integrator.escaped`); a light sample toward a
uniform sky is drawn uniformly over the sphere and mostly lands where the lobes send little. A sun is the other
case: its light samples find it, the BSDF's rarely. Measured (docs/benchmarks.md, "Which light a shadow ray goes
to"): under a directional light and a constant sky, never light-sampling the sky gave 1.3–2.0× less noise than the
uniform choice on the standard swatch and the draped one (weighing it by π L, the irradiance it gives a surface,
1.5–1.9×; by its power, as pbrt-v4's `PowerLightSampler`, more noise than uniform on the standard swatch); under a
directional light and a map with a sun, the uniform choice's noise (weighing the map by its mean radiance instead:
1.3× that).

Where no light has a weight (a uniform sky alone, or with black lights) the lights that send anything share the
choice evenly. A scene with one light draws the one number it always drew and chooses that light.

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
        return peak_irradiance(light.radiance, light.image, above_least=True)
    raise TypeError(f"not a light: {light!r}")


def sends_light(light) -> bool:
    """Whether `light` sends anything anywhere (its values are checked non-negative where it is made)."""
    if isinstance(light, DirectionalLight):
        return bool(np.max(light.irradiance) > 0.0)
    return bool(np.max(light.radiance if light.image is None else light.image) > 0.0)


def selection_cdf(directional: list, environment) -> np.ndarray:
    """float32 cumulative probabilities of the emitters in the kernels' order (the directional lights, then the
    environment if any): entry k is the probability of choosing one of emitters 0..k. The last emitter with any
    weight ends at exactly 1, so that no u ∈ [0, 1) chooses one after it. Where no light has a weight (a uniform sky
    alone, or with black lights), the lights that send anything share the choice evenly, and where none does, all
    of them; empty for a scene without lights."""
    lights = [*directional, *([environment] if environment is not None else [])]
    weight = np.array([light_weight(light) for light in lights], dtype=np.float64)
    if weight.size == 0:
        return np.zeros(0, dtype=np.float32)
    if not weight.sum() > 0.0:
        weight = np.array([float(sends_light(light)) for light in lights])
    if not weight.sum() > 0.0:
        weight = np.ones_like(weight)
    cdf = np.cumsum(weight / weight.sum())
    cdf[int(np.flatnonzero(weight > 0.0)[-1]) :] = 1.0
    return cdf.astype(np.float32)


def selection_probabilities(directional: list, environment) -> np.ndarray:
    """Each emitter's probability of being chosen, in `selection_cdf`'s order: the widths of its steps."""
    return np.diff(selection_cdf(directional, environment), prepend=np.float32(0.0))


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
