"""How the strands lie, as unknowns of the fit (issue 43, item 1): a stated prior over the recipe's parameters a
photographer cannot measure, which the fit averages over and, at its end, estimates with the look.

A photographed swatch's recipe (a [fibers] generator: realisations.py) states what a photographer measures: the
count, width, length, fiber radius, the waves' amplitude and wavelength. How the strands lie within that cannot be
measured, and the recipe only guesses it (`targets photo` writes jitter 0.15 and the generator's layer gap). A
target says which of those it does not know, and over what range (opt-in: without the table nothing changes):

    realisations = "random"
    [arrangement]
    jitter = [0.05, 0.4]            # irregularity, a fraction of the spacing: within [0, 0.4]
    layer_gap = [0.008, 0.014]      # distance between layers, scene units: > 0
    layers = [3, 5]                 # how many layers the count spreads over: integers, 1 to the count
    layer_shift_jitter = [0.0, 1.0] # within [0, 1]: how independent the layers' places across the swatch are
    phase_jitter = [0.0, 0.3]       # wavy and curly only, within [0, 1]: how independent the strands' waves are
    layer_phase_jitter = [0.0, 1.0] # wavy and curly only, within [0, 1]: how independent the layers' waves are
    clump_strength = [0.4, 0.8]     # with clumps, within [0, 1]: how far a clump's strands are pulled together

Each range is a uniform prior, independent of the others (layers uniform over its integers); a range [a, a]
fixes the key at a. `targets photo` writes jitter, layer gap and the layers' places across the swatch (from
staggered to laid independently), and with clumps their strength (`photo_defaults`, below).

Marginalisation. Every realisation the fit renders (its pool's and the realisation term's: realisations.py)
draws these keys from the prior along with its seed and shift, deterministically from (the scene's seed, k)
(`Arrangement.draw`). realisations.py's crossed pairs are then unbiased for the gradient of ½‖Ī(x) − T‖² with Ī
the image averaged over seeds, shifts and the prior: the fit matches the prior-averaged image. Where the
photographed arrangement θ* is a draw from the prior, T = Ī(x*) + e with E[e] = 0 over seed and θ*, so the
estimate is unbiased to first order, as realisations.py shows for seeds alone, and the realisation term of σ (its
K realisations each with their own θ) counts the arrangement's spread with the seed's. Where θ* is no draw from
it (a prior too narrow, an arrangement the recipe cannot make), neither holds: the estimate below says where the
images put θ, and one well outside its range fails the fit (`outside_prior`).

Estimation at the fit's end (`estimate`). The continuous keys (all but layers) are estimated from a linearisation
at the fitted look x̂ and the prior's middle θ̄, jointly with the look: min ‖r + A δx + B δθ‖²_W, with A the fit's
Jacobian, r the weighted residual of the image at (x̂, θ̄) averaged over K realisations, and B = ∂Ī/∂θ the
arrangement's columns, from common-random-number central differences (`columns`): per realisation k (its seed,
shift and layers drawn as the fit draws them), both renders at θ̄ ± δ e_j run the generator with the same seed and
shift and the renderer with the same seed, and (I_k⁺ − I_k⁻)/(2δ) is averaged over k. This is one linearised step
at the end of the fit, not a key stepped inside the Gauss–Newton refinement: the look the fit reports stays the
marginal one, and the step's look (x̂ + δx) is reported beside it as what the look would be at the estimated θ.

Where the gradient is unbiased. Expectation is linear, so whatever numbers the two renders share, E_k[(I_k(θ + δ) −
I_k(θ − δ))/(2δ)] = (Ī(θ + δ) − Ī(θ − δ))/(2δ): the quotient is unbiased for the difference quotient of the
realisation average, always. That is ∂Ī/∂θ up to O(δ²) where Ī is smooth in θ, which holds where each strand moves
continuously with θ and none is added, removed or redrawn: jitter and layer_gap (the strands' axes are affine in
both, generators._swatch_axes; the default spacing and gap follow jitter smoothly), phase_jitter and
layer_phase_jitter (the phases are affine in them), layer_shift_jitter (each deeper layer's place across the
swatch is affine in it, save the strands that wrap from one edge to the other), and clump_strength (a strand's pull
toward its guide is affine in it, generators._clump; the guides are drawn apart from it) with the number of layers
held; a pixel's expected radiance, an integral over its footprint and over the paths, then changes smoothly even
while single strands' edges cross it. It does not hold for `layers`: another number of layers redraws which strand
lies where, so layers is marginalised only. What the common numbers buy is variance: the two renders share the
strands' and the paths' random numbers, so their difference holds the motion's effect and little of the draws'
(tests/test_arrangement.py measures both against independently estimated realisation means).

Reported (params.json "arrangement", the printed table): per continuous key its estimate ± σ (σ from the spread of
the joint step over the K realisations, each's deviation from their mean: the seed's spread and our render noise),
its prior; per look component the arrangement's share of its variance, diag(G B Σ_θ Bᵀ Gᵀ) / σ² with G = H⁻¹AᵀW
the look's gain and Σ_θ the prior's covariance (first order: the part of the realisation term that these columns
count exactly, realisations.py `realisation_spread`), and its σ were θ known (the realisation term without the
arrangement's share) and were θ estimated (the joint step's).
"""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np

from warp_hair.geometry.generators import _MAX_JITTER
from warp_hair.realisation import can_realise, realisation_views
from warp_hair.renderer.prepare import prepare_views
from warp_hair.renderer.render import render
from warp_hair.scene import GENERATORS
from warp_hair.torch import scene_with_controls

# key → (the generators that take it, its allowed range in words, a check of one end). layers's upper end is the
# count, checked with the scene.
KEYS = {
    "jitter": (("swatch", "wavy", "curly"), f"within [0, {_MAX_JITTER}]", lambda v: 0 <= v <= _MAX_JITTER),
    "layer_gap": (("swatch", "wavy", "curly"), "positive, scene units", lambda v: v > 0),
    "layers": (("swatch", "wavy", "curly"), "integers from 1 to the count", lambda v: v >= 1),
    "layer_shift_jitter": (("swatch", "wavy", "curly"), "within [0, 1]", lambda v: 0 <= v <= 1),
    "phase_jitter": (("wavy", "curly"), "within [0, 1]", lambda v: 0 <= v <= 1),
    "layer_phase_jitter": (("wavy", "curly"), "within [0, 1]", lambda v: 0 <= v <= 1),
    "clump_strength": (("swatch", "wavy", "curly"), "within [0, 1], with clumps", lambda v: 0 <= v <= 1),
}
DISCRETE = ("layers",)  # marginalised only: another value redraws the strands (module docstring)
# The central difference's half step, of each key's prior width.
STEP_FRACTION = 0.125
# A key's estimate this many σ beyond its prior's range fails the fit (the prior does not hold).
OUTSIDE_Z = 3.0
# What `targets photo` writes for a recipe: the jitter a photographer cannot see (0.05: nearly a lattice, to 0.4,
# the generator's most) and the gap between layers from touching (2 radii) to 1.75 radii of air between them.
PHOTO_JITTER = (0.05, 0.4)
PHOTO_GAP_RADII = (2.0, 3.75)
# And where each layer lies across the swatch, from the recipe's stagger (0) to layers laid one by one (1, as
# Blender's hair and, likely, a real swatch's): it moves a back-lit view by 10–25% (docs/acceptance.md).
PHOTO_LAYER_SHIFT = (0.0, 1.0)
# And for clumps, how far their strands are pulled together (clump_strength): read off a photo by how far the
# tips close, to about this either side of what the recipe says, within [0, 1].
PHOTO_CLUMP_STRENGTH = 0.2


@dataclasses.dataclass(frozen=True)
class Arrangement:
    """A stated prior over how the strands lie: key → (low, high), uniform (module docstring)."""

    ranges: dict

    @property
    def continuous(self) -> list:
        """The keys estimated at the fit's end: continuous ones whose range is not a point."""
        return [k for k, (a, b) in self.ranges.items() if k not in DISCRETE and b > a]

    @property
    def middle(self) -> dict:
        return {key: 0.5 * (a + b) for key, (a, b) in self.ranges.items() if key not in DISCRETE}

    def draw(self, seed: int, index: int) -> dict:
        """The generator arguments realisation `index` of a scene with fiber seed `seed` takes from the prior
        (always the same for the same seed and index; a stream apart from the realisation's seed and shift)."""
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)], spawn_key=(43,)))
        values = {}
        for key in sorted(self.ranges):  # a fixed order: each key's draw depends on the keys, not on the table
            a, b = self.ranges[key]
            values[key] = int(rng.integers(a, b + 1)) if key in DISCRETE else float(rng.uniform(a, b))
        return values

    def covariance(self, keys) -> np.ndarray:
        """The prior's covariance of `keys` (uniform: width² / 12 each, independent)."""
        return np.diag([(self.ranges[k][1] - self.ranges[k][0]) ** 2 / 12.0 for k in keys])

    def record(self) -> dict:
        return {key: list(value) for key, value in self.ranges.items()}


def fiber_seed(scene) -> int:
    return int(scene.source["fibers"].get("seed", 0))


def parse(table, scenes, where: str) -> Arrangement:
    """target.toml's [arrangement] table, checked against the scenes' [fibers] generator (module docstring);
    errors name `where`, the key and what is allowed."""
    if not isinstance(table, dict) or not table:
        raise ValueError(f"{where}: [arrangement] must be a table of key = [low, high], e.g. jitter = [0.05, 0.4]")
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        raise ValueError(f"{where}: [arrangement] unknown key(s) {unknown}; allowed: {list(KEYS)}")
    scene = scenes[0]
    if not can_realise(scene):
        raise ValueError(f"{where}: [arrangement] needs the scenes' fibers to be a [fibers] generator (a recipe)")
    fibers = scene.source["fibers"]
    generator = fibers["generator"]
    ranges = {}
    for key, value in table.items():
        takers, allowed, ok = KEYS[key]
        name = f"{where}: [arrangement] {key}"
        if generator not in takers:
            raise ValueError(f"{name}: the scenes' generator {generator!r} does not take {key} (only {list(takers)})")
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        ):
            raise ValueError(f"{name} must be a range [low, high] of two numbers, got {value!r}")
        low, high = value
        if key in DISCRETE and not all(isinstance(v, int) for v in value):
            raise ValueError(f"{name} must be a range of integers [low, high], got {value!r}")
        if not (np.isfinite(low) and np.isfinite(high) and low <= high):
            raise ValueError(f"{name} = {value!r}: needs finite low <= high")
        if not (ok(low) and ok(high)):
            raise ValueError(f"{name} = {value!r}: outside the generator's allowed values ({allowed})")
        if key == "layers" and high > int(fibers.get("count", 0) or 0):
            raise ValueError(f"{name} = {value!r}: at most the count ({fibers.get('count')}) strands a layer each")
        ranges[key] = (low, high) if key in DISCRETE else (float(low), float(high))
    # The generator's own rules across the keys (a deep swatch that no longer fits its drape, say): at both corners.
    arguments = {k: v for k, v in fibers.items() if k in inspect.signature(GENERATORS[generator]).parameters}
    for corner in (0, 1):
        values = {key: r[corner] for key, r in ranges.items()}
        try:
            GENERATORS[generator](**{**arguments, **values, "segments": 1})
        except (TypeError, ValueError) as error:
            raise ValueError(f"{where}: [arrangement] at {values}: the generator says: {error}") from None
    return Arrangement(ranges)


def photo_defaults(fibers: dict) -> dict:
    """The [arrangement] `targets photo` writes for a swatch recipe: what a photographer cannot measure off a
    photo, the jitter, the layers' gap and their places across the swatch (PHOTO_JITTER, PHOTO_GAP_RADII,
    PHOTO_LAYER_SHIFT); none for fur. The count and layers
    are counted off the swatch; the waves' phases are what the flags say (a photographer sees whether the waves
    are in step), so they stay in the recipe."""
    if fibers.get("generator") not in KEYS["jitter"][0]:
        return {}
    radius = float(fibers["radius"])
    prior = {
        "jitter": list(PHOTO_JITTER),
        "layer_gap": [round(r * radius, 6) for r in PHOTO_GAP_RADII],
        "layer_shift_jitter": list(PHOTO_LAYER_SHIFT),
    }
    if fibers.get("clumps"):
        strength = float(fibers.get("clump_strength", 0.5))  # the generator's default
        prior["clump_strength"] = [
            round(max(0.0, strength - PHOTO_CLUMP_STRENGTH), 6),
            round(min(1.0, strength + PHOTO_CLUMP_STRENGTH), 6),
        ]
    return prior


# --- estimation at the fit's end --------------------------------------------------------------------------------


def _recipe(arrangement: Arrangement, scene, index: int, at: dict) -> dict:
    """Realisation `index`'s prior draw with the continuous keys set to `at`."""
    return {**arrangement.draw(fiber_seed(scene), index), **at}


def _residual_vector(target, images, gains, settings, rows: int, card_rows) -> np.ndarray:
    """The weighted, pooled residual weight · (gain · I − T) of renders `images` (one per target image), in the
    order linearize.py stacks them (a grey card's rows, if any, zero: no hair there)."""
    from .linearize import loss_weights, pool_like_loss

    parts = []
    for image, rendered, gain in zip(target.images, images, gains):
        reference, _ = pool_like_loss(image, image.image, None, settings.pool)
        weight = loss_weights(reference, settings.loss)
        r, _ = pool_like_loss(image, gain * rendered - image.image, None, settings.pool)
        parts.append(r * weight)
    vector = np.concatenate(parts)
    if card_rows is not None and vector.size != rows:
        full = np.zeros(rows)
        full[~card_rows] = vector
        vector = full
    return vector


def columns(
    target,
    arrangement,
    values,
    keys,
    samples,
    spp,
    seed,
    settings,
    threads=None,
    gains=None,
    rows=None,
    card_rows=None,
    first=0,
    views=None,
):
    """Common-random-number central differences at the prior's middle, per realisation (module docstring).

    Returns (middles (K, N): each realisation's weighted residual at θ̄, the mean of its ± renders;
    columns (K, N, q): each realisation's (r⁺ − r⁻)/(2δ) per key). `values`: the look (and exposure); `gains`: per
    image the factor the renders are multiplied by (default: the exposure's); rows, card_rows: the linearisation's
    number of residuals and its grey card's rows (linearize.py), where it has a card. Realisations are the fit's
    realisation-term ones' successors (indices 1000 + first + k), never those the fit drew. `views(index, recipe)`:
    how they are drawn (default `realisation_views`; the fit's `Realisations.views`, which says once for the fit
    whether strands pass through each other)."""
    from .latents import hair_and_gain

    hair, gain = hair_and_gain(values)
    gains = [np.float32(float(gain))] * len(target.images) if gains is None else gains
    middle = arrangement.middle
    middles, diffs = [], []
    for k in range(samples):
        index = 1000 + first + k
        ups, downs = [], []
        for key in keys:
            step = STEP_FRACTION * (arrangement.ranges[key][1] - arrangement.ranges[key][0])
            pair = []
            for sign in (1, -1):
                at = {**middle, key: middle[key] + sign * step}
                scenes = [image.scene for image in target.images]
                recipe = _recipe(arrangement, scenes[0], index, at)
                drawn = realisation_views(scenes, index, recipe) if views is None else views(index, recipe)
                images = [
                    render(
                        scene_with_controls(view, hair),
                        spp=spp,
                        seed=seed + 7919 * k + j,  # the same for + and −: common random numbers
                        threads=threads,
                    )
                    for j, view in enumerate(prepare_views(drawn))
                ]
                pair.append(_residual_vector(target, images, gains, settings, rows, card_rows))
            ups.append(pair[0])
            downs.append(pair[1])
            diffs.append((pair[0] - pair[1]) / (2 * step))
        middles.append(np.mean([0.5 * (u + d) for u, d in zip(ups, downs)], axis=0))
    q = len(keys)
    stacked = np.array(diffs).reshape(samples, q, -1).transpose(0, 2, 1)
    return np.array(middles), stacked


@dataclasses.dataclass(frozen=True)
class Estimate:
    keys: list
    value: np.ndarray  # (q,) θ̂
    covariance: np.ndarray  # (q, q)
    look_step: np.ndarray  # (p,) δx of the joint step: the look at θ̂ is x̂ + δx
    look_sigma_joint: np.ndarray  # (p,) the look's σ from the joint step's spread

    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))


def estimate(arrangement: Arrangement, keys, look_jacobian, weights, middles, crn_columns) -> Estimate:
    """The joint linearised step from (x̂, θ̄) (module docstring). look_jacobian (N, p): the fit's A at x̂;
    weights (N,); middles (K, N) and crn_columns (K, N, q) from `columns`."""
    b = crn_columns.mean(axis=0)
    k = len(middles)
    joint = np.concatenate([look_jacobian, b], axis=1)
    normal = joint.T @ (weights[:, None] * joint)
    gain = np.linalg.pinv(normal) @ (joint * weights[:, None]).T  # (p + q, N)
    residual = middles.mean(axis=0)
    step = -gain @ residual
    deviations = middles - residual
    spread = (gain @ deviations.T).T  # (K, p + q)
    covariance = spread.T @ spread / max(k - 1, 1)
    p = look_jacobian.shape[1]
    value = np.array([arrangement.middle[key] for key in keys]) + step[p:]
    return Estimate(
        list(keys),
        value,
        covariance[p:, p:],
        step[:p],
        np.sqrt(np.diag(covariance[:p, :p])),
    )


def outside_prior(arrangement: Arrangement, result: Estimate) -> list[str]:
    """Failure reasons (verdict.py's form) for keys the images put more than OUTSIDE_Z σ beyond the prior's
    range: the fit averaged over arrangements that do not describe the images, so its look is biased."""
    reasons = []
    for key, value, sigma in zip(result.keys, result.value, result.sigma()):
        low, high = arrangement.ranges[key]
        beyond = max(low - value, value - high, 0.0)
        if beyond > OUTSIDE_Z * sigma:
            reasons.append(
                f"the images put the strands' {key} at {value:.3g} ± {sigma:.2g}, outside the prior "
                f"[{low:g}, {high:g}] the fit averaged over (target.toml [arrangement]): its look is that of other "
                f"strands. Widen the range where the generator allows ({KEYS[key][1]}), or check the recipe "
                "against the photo (another generator, clumps, waves); the look at the estimated arrangement is in "
                "params.json"
            )
    return reasons


def record(
    arrangement: Arrangement,
    found: Estimate,
    names,
    values: dict,
    look_variance,
    arrangement_variance,
    samples: int,
    spp: int,
):
    """params.json's "arrangement": the prior, each key's estimate ± σ, the look at the estimate, the arrangement's
    share of the look's variance, the look's σ were θ known and were it estimated (module docstring); and the
    failures where the images put a key outside its prior (`outside_prior`). look_variance (p,): the fit's σ² of
    the look; arrangement_variance (p,): its part the arrangement makes, as the realisation term counts it
    (realisations.py `realisation_spread`)."""
    from .latents import SPECS, flat_values
    from .uncertainty import component_labels

    labels = component_labels(names)
    flat = flat_values({name: values[name] for name in names})
    moved, look, start = flat + found.look_step, {}, 0
    for name in names:
        size = SPECS[name].size
        part = moved[start : start + size].tolist()
        look[name] = part if size == 3 else part[0]
        start += size
    return {
        "prior": arrangement.record(),
        "estimate": {
            key: {"value": float(v), "sigma": float(s), "prior": list(arrangement.ranges[key])}
            for key, v, s in zip(found.keys, found.value, found.sigma())
        },
        "look_at_estimate": look,
        # Components the linear step takes outside their control's range (an albedo below 0, say): there one
        # step from the prior's middle is no look, only the direction the arrangement pulls it.
        "look_at_estimate_outside": _outside_ranges(look, labels),
        "look_share_of_variance": {
            label: float(part / max(total, 1e-300))
            for label, total, part in zip(labels, look_variance, arrangement_variance)
        },
        "look_sigma_arrangement_known": {
            label: float(np.sqrt(max(total - part, 0.0)))
            for label, total, part in zip(labels, look_variance, arrangement_variance)
        },
        "look_sigma_joint_step_spread": {label: float(v) for label, v in zip(labels, found.look_sigma_joint)},
        "samples": samples,
        "spp": spp,
        "method": "one linearised joint step at the fit's end from the prior's middle; CRN central differences "
        "(optimize/arrangement.py); the fitted values stay those averaged over the prior",
        "failures": outside_prior(arrangement, found),
    }


def _outside_ranges(look: dict, labels) -> list[str]:
    """The labels of `look`'s components outside their control's allowed range (warp_hair.controls)."""
    from warp_hair.controls import CONTROLS

    flat = [
        (name, value) for name, values in look.items() for value in (values if isinstance(values, list) else [values])
    ]
    return [
        label
        for label, (name, value) in zip(labels, flat)
        if (name in CONTROLS and not CONTROLS[name].contains(value)) or (name not in CONTROLS and value <= 0)
    ]
