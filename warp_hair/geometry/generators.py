"""Procedural fiber assemblies: straight, wavy and curly swatches and a fur patch, each seeded and listed root
first. Scene units throughout: swatches lie along +y in the x–y plane, facing +z, centred on the origin, their
strands ordered layer by layer (the front layer first), left to right in a layer."""

from __future__ import annotations

import inspect
import math
import operator

import numpy as np

from .. import validate
from .assembly import FiberAssembly

# A swatch fiber wanders sideways by up to this fraction of jitter × spacing. With the ±jitter/2 root jitter,
# neighbours in a layer then stay at least spacing × (1 − (1 + 2·_WANDER)·jitter) apart.
_WANDER = 0.125
# Above this the jitter could push fiber axes past the documented width of the swatch.
_MAX_JITTER = 0.4
# The default spacing is this much more than the spacing at which neighbours could just touch, so that
# float32 rounding never makes them overlap.
_SPACING_MARGIN = 1.05
# The default segments of a wavy fiber per wavelength, of a curly one per turn.
WAVE_SEGMENTS, CURL_SEGMENTS = 12, 16


def swatch(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    spacing=None,
    jitter=0.25,
    segments=8,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
    shift=0.0,
    layer_shift_jitter=0.0,
    clumps=0,
    clump_strength=None,
    strays=0,
    stray_lift=None,
):
    """A flat swatch of straight, parallel fibers, like a hair swatch card.

    Fibers run along +y from their roots at y = −length/2 to their tips at +length/2 and spread across x, in `layers`
    layers stacked
    towards −z: layer k lies near z = −k·layer_gap, so layer 0 (at z = 0) faces a camera on +z. Odd layers are
    offset by half a spacing to cover the gaps between the fibers of even ones, so the swatch has no
    see-through gaps. Strands are ordered layer by layer, left to right; when `layers` does not divide
    `count`, the first `count % layers` layers hold one fiber more.

    Args:
        count: number of fibers.
        layers: number of layers, 1 to `count`.
        length: fiber length along y, scene units.
        radius: fiber radius, scene units, the same at every vertex.
        spacing: distance between neighbouring fiber axes within a layer, scene units. Default: from `width`
            when given (width / fibers per layer), else 2.1·radius / (1 − 1.25·jitter), just over the spacing
            at which neighbours in a layer could touch (0.0122 with the other defaults).
        jitter: irregularity as a fraction of `spacing`, in [0, 0.4]: each fiber moves by up to ±jitter/2 ×
            spacing in x and in z, and wanders sideways (x) along its length by up to ±jitter/8 × spacing.
        segments: straight segments per fiber (segments + 1 vertices, evenly spaced in y).
        width: extent of the swatch across x, scene units: every fiber axis stays within |x| ≤ width/2.
            Default: spacing × fibers per layer (1.95 with the other defaults). Give `spacing` or `width`, not
            both.
        seed: seed of the NumPy random generator; a seed always gives the same swatch.
        layer_gap: distance between neighbouring layers along z, scene units. Default: 2·radius +
            jitter·spacing, at which fibers of different layers never touch.
        drape: radius of a cylinder (axis along x, top at z = 0) to lay the swatch over, scene units, above
            length / π; default flat. Shows the highlight band of swatch photographs (see `_swatch_assembly`).
        shift: moves every fiber across the swatch by shift × spacing, in [0, 1), those pushed past the edge
            wrapping round to the other, so that the swatch keeps its width and density: with another seed, another
            realisation of the same recipe (`warp_hair.realisation`). Jitter and wander are drawn as they are
            without it; a wrapped fiber's may take its axis up to 5/8 jitter × spacing past the width.
        layer_shift_jitter: how independent the layers' places across the swatch are, in [0, 1]: layer k > 0
            moves by a further offset uniform in [0, layer_shift_jitter) spacings, wrapping as for `shift`. 0 (the
            default) keeps odd layers over the even ones' gaps; 1 places each layer independently, as in a swatch
            laid layer by layer (the gaps of deeper layers then line up with the front's as often as not).
        clumps: number of clumps the fibers gather into, 0 (the default: none) to `count`. Each clump's guide is a
            fiber drawn at random; every fiber joins the guide nearest to it across the swatch (in x at the root),
            so a clump is a lock of neighbouring fibers through every layer.
        clump_strength: how far a clump's fibers are pulled toward their guide, in [0, 1]: a fiber moves towards
            the guide's own curve (x and z) by clump_strength × its height from root (0) to tip (1), so at
            strength 1 the tips meet on the guide. Default 0.5; only with `clumps`.
        strays: number of stray fibers, 0 (the default) to the front layer's fiber count: fibers of the front
            layer drawn at random that leave the swatch's surface (towards +z, outward over a drape) from a point
            drawn in the first three quarters of their length, rising as the square of the distance from there,
            to a height at the tip uniform in [½, 1] × `stray_lift` and drifting sideways by up to half that.
        stray_lift: the greatest height of a stray's tip above the surface, scene units. Default: a tenth of
            `length`; only with `strays`.

    Clump guides, strays and their shapes are drawn from the seed in streams of their own, apart from the
    jitter's: a recipe without them gives the fibers it always gave, and another seed draws them afresh.

    With the default spacing and layer gap no two fibers intersect. A smaller spacing, or a `width` that
    implies one, packs them tighter and lets neighbours overlap.
    """
    _, y, x, z = _straight_swatch(
        count, layers, length, radius, spacing, jitter, segments, width, seed, layer_gap, shift, layer_shift_jitter
    )
    x, z = _groom(x, y, z, count, layers, seed, clumps, clump_strength, strays, stray_lift)
    return _swatch_assembly(x, y, z, radius, drape)


def wavy(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    amplitude=0.02,
    wavelength=0.2,
    phase_jitter=0.15,
    spacing=None,
    jitter=0.25,
    segments=None,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
    shift=0.0,
    layer_shift_jitter=0.0,
    phase=None,
    layer_phase_jitter=0.0,
    clumps=0,
    clump_strength=None,
    strays=0,
    stray_lift=None,
):
    """A swatch of wavy fibers: the fibers of `swatch`, each swinging in x as amplitude·sin(2π·y/wavelength + phase).

    Args:
        count, layers, length, radius, spacing, jitter, width, seed, layer_gap, drape, shift, layer_shift_jitter,
            clumps, clump_strength, strays, stray_lift: as for `swatch` (fiber axes reach up to `amplitude` beyond
            its width; `length` is the extent along y, not the arc length). A clump's fibers take on its guide's
            wave towards their tips.
        amplitude: half the peak-to-peak swing of a wave in x, scene units.
        wavelength: length of one wave along y, scene units.
        phase_jitter: how independent the fibers' waves are, in [0, 1]. Each fiber's phase is its layer's phase
            plus a random offset uniform in [0, 2π·phase_jitter): 0 gives waves in step, as in a combed wavy
            swatch, 1 independent waves. Fibers out of step cross their neighbours.
        phase: the phase of the front layer's waves, radians (of every layer's with `layer_phase_jitter` 0): where
            its waves crest, a property of the swatch at the scale of many fibers. Default: drawn from the seed
            (`shared_phase`).
        layer_phase_jitter: how independent the layers' waves are, in [0, 1]: layer k > 0 waves at `phase` plus
            an offset uniform in [0, 2π·layer_phase_jitter), as in a swatch combed layer by layer; 0 (the
            default) gives every layer the same phase, 1 independent layers.
        segments: straight segments per fiber. Default: 12 per wavelength, ceil(12·length / wavelength).
    """
    _check_positive(amplitude=amplitude, wavelength=wavelength)
    segments = _segments_per_period(segments, length, wavelength, WAVE_SEGMENTS, "wavelength")
    rng, y, x, z = _straight_swatch(
        count, layers, length, radius, spacing, jitter, segments, width, seed, layer_gap, shift, layer_shift_jitter
    )
    phases = _fiber_phases(count, phase_jitter, rng, phase) + _layer_phases(count, layers, layer_phase_jitter, seed)
    x = x + amplitude * np.sin(phases[:, None] + 2 * np.pi * y / wavelength)
    x, z = _groom(x, y, z, count, layers, seed, clumps, clump_strength, strays, stray_lift)
    return _swatch_assembly(x, y, z, radius, drape)


def curly(
    count=640,
    layers=4,
    length=1.4,
    radius=0.004,
    curl_radius=0.02,
    pitch=0.1,
    phase_jitter=1.0,
    spacing=None,
    jitter=0.25,
    segments=None,
    width=None,
    seed=0,
    layer_gap=None,
    drape=None,
    shift=0.0,
    layer_shift_jitter=0.0,
    phase=None,
    layer_phase_jitter=0.0,
    clumps=0,
    clump_strength=None,
    strays=0,
    stray_lift=None,
):
    """A swatch of curly fibers: helices around the fiber axes of `swatch`, all turning the same way.

    Each fiber is (x + curl_radius·cos a, y, z + curl_radius·sin a) with a = 2π·y/pitch + phase.

    Args:
        count, layers, length, radius, spacing, jitter, width, seed, layer_gap, drape, shift, layer_shift_jitter,
            clumps, clump_strength, strays, stray_lift: as for `swatch` (fibers reach up to `curl_radius` beyond its
            width and layers; `length` is the extent along y, not the arc length).
        curl_radius: radius of the helix, scene units.
        pitch: rise along y per turn, scene units.
        phase_jitter: how independent the fibers' curls are, in [0, 1]. Each fiber's phase is its layer's phase
            plus a random offset uniform in [0, 2π·phase_jitter): 1 gives independent curls, 0 curls in step (one
            ringlet-like sheet).
        phase: the phase of the front layer's curls, radians; default: drawn from the seed (`shared_phase`).
        layer_phase_jitter: how independent the layers' curls are, in [0, 1], as for `wavy`.
        segments: straight segments per fiber. Default: 16 per turn, ceil(16·length / pitch).
    """
    _check_positive(curl_radius=curl_radius, pitch=pitch)
    segments = _segments_per_period(segments, length, pitch, CURL_SEGMENTS, "pitch")
    rng, y, x, z = _straight_swatch(
        count, layers, length, radius, spacing, jitter, segments, width, seed, layer_gap, shift, layer_shift_jitter
    )
    phases = _fiber_phases(count, phase_jitter, rng, phase) + _layer_phases(count, layers, layer_phase_jitter, seed)
    angle = phases[:, None] + 2 * np.pi * y / pitch
    x, z = x + curl_radius * np.cos(angle), z + curl_radius * np.sin(angle)
    x, z = _groom(x, y, z, count, layers, seed, clumps, clump_strength, strays, stray_lift)
    return _swatch_assembly(x, y, z, radius, drape)


def fur(
    count=2000,
    patch=0.5,
    length=0.1,
    root_radius=0.0015,
    tip_radius=0.0003,
    lean=30.0,
    bend=20.0,
    length_jitter=0.2,
    segments=6,
    seed=0,
):
    """Short fur fibers rising along +z from a base patch in the x–y plane (z = 0), centred on the origin.

    Each fiber leans away from +z towards its own random azimuth, and bends further that way towards the tip.
    Strand vertex 0 is the root.

    Args:
        count: number of fibers.
        patch: size of the base patch, scene units: the side of a square, or (extent in x, extent in y).
            Roots are uniformly random inside it.
        length: mean fiber length (along the fiber), scene units.
        root_radius: fiber radius at the root, scene units.
        tip_radius: fiber radius at the tip, scene units; the radius tapers linearly from root to tip.
        lean: largest lean of a fiber's root from +z, degrees; each fiber leans by a uniform random angle in
            [0, lean] towards a uniformly random azimuth.
        bend: extra lean gathered from root to tip, degrees, in the fiber's own lean direction. lean + bend must
            stay below 90 so that every fiber keeps rising.
        length_jitter: each fiber's length is length·(1 + u) with u uniform in [−length_jitter, length_jitter];
            in [0, 1).
        segments: straight segments per fiber.
        seed: seed of the NumPy random generator; a seed always gives the same fur.
    """
    _check_size(count, segments)
    _check_positive(length=length, root_radius=root_radius, tip_radius=tip_radius)
    if not (lean >= 0 and bend >= 0 and lean + bend < 90):
        raise ValueError(f"lean and bend must be >= 0 with lean + bend < 90 degrees, got {lean} and {bend}")
    if not 0 <= length_jitter < 1:
        raise ValueError(f"length_jitter must be in [0, 1), got {length_jitter}")
    rng = np.random.default_rng(seed)
    roots = _patch_roots(patch, count, rng)
    lengths = length * (1 + length_jitter * rng.uniform(-1, 1, count))
    root_lean = np.radians(lean) * rng.uniform(0, 1, count)
    azimuth = rng.uniform(0, 2 * np.pi, count)
    # Each segment points along the fiber's lean at its midpoint, which grows linearly from root to tip.
    midpoint = (np.arange(segments) + 0.5) / segments
    tilt = root_lean[:, None] + np.radians(bend) * midpoint
    steps = (
        np.stack(
            [np.sin(tilt) * np.cos(azimuth)[:, None], np.sin(tilt) * np.sin(azimuth)[:, None], np.cos(tilt)], axis=-1
        )
        * (lengths / segments)[:, None, None]
    )
    offsets = np.concatenate([np.zeros((count, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    radii = np.linspace(root_radius, tip_radius, segments + 1)
    return FiberAssembly.from_arrays(roots[:, None, :] + offsets, np.broadcast_to(radii, (count, segments + 1)))


def _straight_swatch(
    count, layers, length, radius, spacing, jitter, segments, width, seed, layer_gap, shift=0.0, layer_shift_jitter=0.0
):
    """What every swatch starts from: the seeded generator (the caller's own draws follow its), the heights y (N,)
    and the straight fiber axes x, z (S, N)."""
    _check_size(count, segments)
    rng = np.random.default_rng(seed)
    y = _heights(length, segments)
    layer_shifts = _layer_shifts(layers, layer_shift_jitter, seed)
    x, z = _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng, shift, layer_shifts)
    return rng, y, x, z


def _heights(length, segments):
    _check_positive(length=length)
    _check_count(segments=segments)
    return np.linspace(-length / 2, length / 2, segments + 1)


def _segments_per_period(segments, length, period, per_period, name):
    if segments is not None:
        return segments
    _check_positive(length=length, **{name: period})
    needed = per_period * length / period
    if not needed <= validate.INT32_MAX:
        raise ValueError(
            f"{name} = {period!r} over length {length!r} needs {needed:.3g} segments per fiber ({per_period} per "
            f"period), more than {validate.INT32_MAX}; give a longer {name} or set segments"
        )
    return math.ceil(needed)


# Peak bytes per vertex while a generator builds its arrays (tracemalloc: 20 000 fibers of 20 segments, ~100).
_GENERATOR_BYTES_PER_VERTEX = 128


def _check_size(count, segments):
    """Before allocating: count fibers of `segments` segments must fit int32 indices and the free memory."""
    _check_count(count=count, segments=segments)
    vertices = operator.index(count) * (operator.index(segments) + 1)
    if vertices > validate.INT32_MAX:
        raise ValueError(
            f"{count} fibers of {segments} segments make {vertices} vertices, more than the {validate.INT32_MAX} a "
            "fiber assembly indexes"
        )
    validate.memory(
        f"{count} fibers of {segments} segments ({vertices} vertices)", vertices * _GENERATOR_BYTES_PER_VERTEX
    )


def _swatch_axes(y, count, layers, radius, spacing, width, jitter, layer_gap, rng, shift=0.0, layer_shifts=None):
    """x and z (S, N) of straight swatch fibers at heights y (N,): jittered, staggered roots plus wander.
    layer_shifts: per layer, a further shift in spacings (`_layer_shifts`), or None."""
    _check_count(count=count, layers=layers)
    if layers > count:
        raise ValueError(f"layers must be at most count, got {layers} layers for {count} fibers")
    _check_positive(radius=radius)
    if not 0 <= jitter <= _MAX_JITTER:
        raise ValueError(f"jitter must be in [0, {_MAX_JITTER}], got {jitter}")
    sizes = _layer_sizes(count, layers)
    spacing = _swatch_spacing(int(sizes[0]), radius, spacing, width, jitter)
    layer_gap = 2 * radius + jitter * spacing if layer_gap is None else layer_gap
    _check_positive(layer_gap=layer_gap)

    layer = np.repeat(np.arange(layers), sizes)
    index_in_layer = np.arange(count) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    stagger = np.where(layer % 2 == 1, 0.25, -0.25) if layers > 1 else 0.0
    position = index_in_layer + stagger  # along the layer, in spacings
    if shift:
        shift = validate.real("shift", shift)
        if not 0 <= shift < 1:
            raise ValueError(f"shift must be in [0, 1) (a fraction of the spacing), got {shift!r}")
    if layer_shifts is not None:
        shift = shift + layer_shifts[layer]
    if np.any(shift):
        # Wrapped into [−½, n − ½) spacings: the lattice is periodic in n spacings, so wrapping keeps it.
        position = np.mod(position + shift + 0.5, sizes[layer]) - 0.5
        position = position[np.lexsort((position, layer))]  # left to right in each layer again
    x = (position - (sizes[layer] - 1) / 2) * spacing
    x += jitter * spacing * rng.uniform(-0.5, 0.5, count)
    z = -layer * layer_gap + jitter * spacing * rng.uniform(-0.5, 0.5, count)

    # One slow sideways bow per fiber, at most one wave over its length, so neighbours stay roughly parallel.
    extent = y[-1] - y[0]
    wander = _WANDER * jitter * spacing * rng.uniform(-1, 1, count)
    wander_wavelength = extent * rng.uniform(1, 2, count)
    wander_phase = rng.uniform(0, 2 * np.pi, count)
    bow = np.sin(2 * np.pi * y / wander_wavelength[:, None] + wander_phase[:, None])
    return x[:, None] + wander[:, None] * bow, np.repeat(z[:, None], len(y), axis=1)


def _layer_shifts(layers, layer_shift_jitter, seed):
    """Per layer, its shift across the swatch beyond the stagger, in spacings (0 for the front layer), or None with
    layer_shift_jitter 0. Layer k > 0 moves by an offset uniform in [0, layer_shift_jitter): 0 keeps alternate
    layers half a spacing apart (each layer's fibers over the gaps of the one in front), 1 makes the layers'
    places across the swatch independent, as in layers laid one by one. Affine in layer_shift_jitter."""
    layer_shift_jitter, draws = _layer_draws("layer_shift_jitter", layer_shift_jitter, layers, seed, _LAYER_SHIFTS)
    return None if draws is None else layer_shift_jitter * draws


def _layer_draws(name, value, layers, seed, purpose):
    """(value checked to lie in [0, 1], per layer a draw uniform in [0, 1) from the key's own stream with the front
    layer's 0), or (value, None) where value is 0: what a per-layer key (layer_phase_jitter, layer_shift_jitter)
    scales, its draws apart from every other key's."""
    value = validate.real(name, value)
    if not 0 <= value <= 1:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    if value == 0:
        return value, None
    draws = _stream(seed, purpose).uniform(0, 1, layers)
    draws[0] = 0.0  # the front layer stays: its waves at `phase`, its place where the lattice puts it
    return value, draws


def _layer_sizes(count, layers):
    """Fibers per layer: the first `count % layers` layers hold one more."""
    sizes = np.full(layers, count // layers)
    sizes[: count % layers] += 1
    return sizes


def _layer_of(count, layers):
    """Each fiber's layer (strands are listed layer by layer)."""
    return np.repeat(np.arange(layers), _layer_sizes(count, layers))


def _stream(seed, purpose):
    """A random generator for one of the later keys (_LAYER_PHASES, _CLUMPS, _STRAYS, _LAYER_SHIFTS), independent of
    the seed's main generator and of each other (NumPy's spawned seed sequences): the draws of a recipe without
    those keys stay what they were, and one key's draws do not move when another's are added."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(purpose,)))


_LAYER_PHASES, _CLUMPS, _STRAYS, _LAYER_SHIFTS = 1, 2, 3, 4
# A stray leaves the surface somewhere in the first this fraction of its length.
_STRAY_DEPARTURE = 0.75


def _layer_phases(count, layers, layer_phase_jitter, seed):
    """Per fiber, its layer's phase offset (0 for the front layer), or 0.0 with layer_phase_jitter 0."""
    layer_phase_jitter, draws = _layer_draws("layer_phase_jitter", layer_phase_jitter, layers, seed, _LAYER_PHASES)
    if draws is None:
        return 0.0
    return (2 * np.pi * layer_phase_jitter * draws)[_layer_of(count, layers)]


def _groom(x, y, z, count, layers, seed, clumps, clump_strength, strays, stray_lift):
    """The fiber axes x, z (S, N) at heights y (N,) gathered into clumps, then with strays lifted off the front."""
    x, z = _clump(x, y, z, count, seed, clumps, clump_strength)
    return _stray(x, y, z, count, layers, seed, strays, stray_lift)


def _clump(x, y, z, count, seed, clumps, clump_strength):
    clumps = validate.integer("clumps", clumps, minimum=0, maximum=None)
    if clumps > count:
        raise ValueError(f"clumps must be at most the {count} fibers, got {clumps}")
    if not clumps:
        if clump_strength is not None:
            raise ValueError("clump_strength needs clumps (the number of clumps, at least 1)")
        return x, z
    strength = 0.5 if clump_strength is None else validate.real("clump_strength", clump_strength)
    if not 0 <= strength <= 1:
        raise ValueError(f"clump_strength must be in [0, 1], got {strength!r}")
    guides = _stream(seed, _CLUMPS).choice(count, clumps, replace=False)
    # Each fiber joins the guide nearest across the swatch at the root: the one sorted just left or right of it.
    root, order = x[:, 0], np.argsort(x[guides, 0], kind="stable")
    ranked = root[guides][order]
    right = np.clip(np.searchsorted(ranked, root), 0, clumps - 1)
    left = np.clip(right - 1, 0, clumps - 1)
    nearer = np.where(np.abs(root - ranked[left]) <= np.abs(root - ranked[right]), left, right)
    guide = guides[order][nearer]
    pull = strength * (y - y[0]) / (y[-1] - y[0])
    return x + pull * (x[guide] - x), z + pull * (z[guide] - z)


def _stray(x, y, z, count, layers, seed, strays, stray_lift):
    front = np.flatnonzero(_layer_of(count, layers) == 0)
    strays = validate.integer("strays", strays, minimum=0, maximum=None)
    if strays > len(front):
        raise ValueError(
            f"strays must be at most the front layer's {len(front)} fibers (strays leave the swatch's front "
            f"surface), got {strays}"
        )
    if not strays:
        if stray_lift is not None:
            raise ValueError("stray_lift needs strays (the number of stray fibers, at least 1)")
        return x, z
    extent = y[-1] - y[0]
    lift = extent / 10 if stray_lift is None else validate.real("stray_lift", stray_lift)
    _check_positive(stray_lift=lift)
    rng = _stream(seed, _STRAYS)
    chosen = rng.choice(front, strays, replace=False)
    departure = _STRAY_DEPARTURE * rng.uniform(0, 1, strays)[:, None]
    height = lift * rng.uniform(0.5, 1, strays)[:, None]
    drift = height * rng.uniform(-0.5, 0.5, strays)[:, None]
    # Rising as the square of the distance from where it leaves: its tangent turns smoothly away from the surface.
    rise = (np.clip((y - y[0]) / extent - departure, 0, None) / (1 - departure)) ** 2
    x, z = x.copy(), z.copy()
    x[chosen] += drift * rise
    z[chosen] += height * rise
    return x, z


def _swatch_spacing(per_layer, radius, spacing, width, jitter):
    if spacing is not None and width is not None:
        raise ValueError("give spacing or width, not both")
    if width is not None:
        _check_positive(width=width)
        return width / per_layer
    if spacing is not None:
        _check_positive(spacing=spacing)
        return spacing
    closest = 1 - (1 + 2 * _WANDER) * jitter
    return _SPACING_MARGIN * 2 * radius / closest


def _fiber_phases(count, phase_jitter, rng, phase=None):
    if not 0 <= phase_jitter <= 1:
        raise ValueError(f"phase_jitter must be in [0, 1], got {phase_jitter}")
    shared = rng.uniform(0, 2 * np.pi)  # drawn even when given, so that the fibers' own draws stay the same
    if phase is not None:
        shared = validate.real("phase", phase)
    return shared + 2 * np.pi * phase_jitter * rng.uniform(0, 1, count)


def shared_phase(generator, **arguments) -> float:
    """The phase `wavy` or `curly` (`generator`) shares among its fibers when `phase` is not given, for these
    arguments and the generator's own defaults for the rest (the waves' own arguments do not change it)."""
    bound = inspect.signature(generator).bind(**arguments)
    bound.apply_defaults()
    a = bound.arguments
    rng, *_ = _straight_swatch(
        a["count"], a["layers"], a["length"], a["radius"], a["spacing"], a["jitter"], 1, a["width"], a["seed"],
        a["layer_gap"], a["shift"], a["layer_shift_jitter"],
    )  # fmt: skip
    return float(rng.uniform(0, 2 * np.pi))


def _swatch_assembly(x, y, z, radius, drape=None):
    """The assembly of fibers with axes (x, y, z); with `drape`, the swatch is laid over a cylinder.

    Draping bends the flat swatch over a cylinder of radius `drape` whose axis runs along x at z = −drape, the
    way hair swatches are photographed: (y, z) → ((drape + z) sin(y/drape), (drape + z) cos(y/drape) − drape).
    Layer 0 lies on the cylinder, deeper layers inside it, and lengths along y become arc lengths. Seen from +z
    the fibers' tangents then sweep through a range of angles, so one image shows the highlight band whose
    position and width the longitudinal controls (α, β_m) set; a flat swatch shows one angle only.
    """
    y = np.broadcast_to(y, x.shape)
    if drape is not None:
        _check_positive(drape=drape)
        half_angle = np.abs(y).max() / drape
        if half_angle >= np.pi / 2:
            raise ValueError(
                f"drape = {drape} is too tight for the swatch's length: it must exceed length / π = "
                f"{2 * np.abs(y).max() / np.pi:.4g}"
            )
        if (z <= -drape).any():
            raise ValueError(f"drape = {drape} is smaller than the swatch's depth {-z.min():.4g}")
        bent = drape + z
        y, z = bent * np.sin(y / drape), bent * np.cos(y / drape) - drape
    points = np.stack([x, y, z], axis=-1)
    return FiberAssembly.from_arrays(points, radius)


def _patch_roots(patch, count, rng):
    """Roots uniform in the patch; errors name `patch` as the user wrote it: one number, or a pair."""
    sizes = np.asarray(patch, dtype=object)
    if sizes.size == 1 and sizes.ndim <= 1:
        extent_x = extent_y = validate.real("patch", sizes.ravel()[0])
        _check_positive(patch=extent_x)
    elif sizes.shape == (2,):
        extent_x, extent_y = (validate.real(f"patch[{k}]", v) for k, v in enumerate(sizes))
        _check_positive(**{"patch[0]": extent_x, "patch[1]": extent_y})
    else:
        raise ValueError(f"patch must be one number (a square's side) or two (extent in x, in y), got {patch!r}")
    x = rng.uniform(-extent_x / 2, extent_x / 2, count)
    y = rng.uniform(-extent_y / 2, extent_y / 2, count)
    return np.column_stack([x, y, np.zeros(count)])


def _check_positive(**values):
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def _check_count(**values):
    for name, value in values.items():
        if operator.index(value) < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
