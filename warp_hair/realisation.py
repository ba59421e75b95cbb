"""Other realisations of a scene's generated fibers: the same recipe, other strands.

    other = realisation(scene, 3)     # the scene with its [fibers] generator run again: realisation 3

A scene whose fibers come from a generator (`[fibers] generator = "swatch"`, "wavy", "curly") describes a groom
by its statistics: the recipe's parameters say how many strands, how far apart and how they wave, and its seed
picks one set of strands out of all those the recipe makes. A photographed swatch is one more such set, never
the one the seed picks. `realisation(scene, k)` runs the generator again with a seed drawn from (the scene's
seed, k), and for the swatch recipes a `shift` across the swatch uniform in [0, 1) of a spacing as well: the
seed alone only re-jitters the strands around the same lattice (by ±jitter/2 of a spacing), whereas an
independent swatch's lattice lies anywhere across a spacing. What every realisation keeps is the recipe and
the swatch's look at the scale of many fibers, which a scene "like" a photographed swatch states: its width,
density, and for wavy and curly fibers the phase their waves share (where the swatch's waves crest, `phase`;
with phase_jitter 0 the waves of a whole layer crest together, and redrawing that would move a pattern the
image shows as plainly as its highlight band: on the Cycles dark wavy swatch it moved a fit's β_n by 0.04).
With `layer_phase_jitter` that phase is the front layer's, which is kept; the deeper layers' offsets from it,
the clump guides (`clumps`), which fibers stray and how (`strays`) are drawn from the seed, and so redrawn,
while the recipe's numbers (how many clumps and how strongly they pull, how many strays and how far they
lift, how independent the layers' waves are) stay as stated.
Realisation k of a scene is always the same, and k = 0 is the scene itself.

`realisation(scene, k, recipe)` first replaces generator arguments of the recipe (`recipe`, e.g. {"jitter": 0.3}):
the fit's draw of how the strands lie from a stated prior (optimize/arrangement.py). The seed, shift and phase are
drawn as without it, so two such realisations with the same k differ only by what `recipe` changes: the same
strands moved (common random numbers), except where it changes how many strands a layer holds.
"""

from __future__ import annotations

import copy
import dataclasses
import inspect

import numpy as np

from .geometry.generators import shared_phase
from .scene import GENERATORS, Scene, check_scene, scene_from_dict

# The generators whose strands lie on a lattice across the swatch, which `shift` moves (generators.py).
SHIFTED_GENERATORS = frozenset({"swatch", "wavy", "curly"})
# The generators whose strands' waves share a phase: where the swatch's waves crest, which every realisation keeps.
WAVED_GENERATORS = frozenset({"wavy", "curly"})


def can_realise(scene: Scene) -> bool:
    """Whether the scene's fibers come from a generator, whose recipe another realisation can be drawn from."""
    return "generator" in scene.source.get("fibers", {})


def check_realisable(scene: Scene, where: str) -> None:
    """A ValueError naming `where` when the scene's fibers are a file (a groom is what it is: no recipe to draw
    other strands from)."""
    if not can_realise(scene):
        fibers = scene.source.get("fibers", {})
        raise ValueError(
            f"{where}: other realisations of the fibers need a [fibers] generator (a recipe), but its fibers come "
            f"from file {fibers.get('file', '?')!r}; describe them by a generator (swatch, wavy, curly, fur) or "
            "render the file's own strands"
        )


def realisation_draw(scene: Scene, index: int, recipe: dict | None = None) -> dict:
    """The generator arguments that realisation `index` changes: its seed (and shift, for a swatch)."""
    fibers = {**scene.source["fibers"], **(recipe or {})}
    base_seed = int(fibers.get("seed", 0))
    state = np.random.SeedSequence([base_seed, int(index)]).generate_state(2)
    draw = {"seed": int(state[0])}
    if fibers["generator"] in SHIFTED_GENERATORS:
        draw["shift"] = float(state[1]) / 2**32
    if fibers["generator"] in WAVED_GENERATORS and "phase" not in fibers:
        generator = GENERATORS[fibers["generator"]]
        # The generator's own arguments: not how the strands are drawn (curve, tolerance) or their random values.
        accepted = inspect.signature(generator).parameters
        arguments = {key: value for key, value in fibers.items() if key in accepted}
        draw["phase"] = shared_phase(generator, **arguments)
    return draw


def realisation(scene: Scene, index: int, recipe: dict | None = None) -> Scene:
    """The scene with realisation `index` of its fibers' recipe (see the module docstring); index 0 is the scene.
    `recipe`: generator arguments that replace the scene's first (index 0 then draws nothing else)."""
    check_realisable(scene, str(scene.path or "scene"))
    if index == 0 and not recipe:
        return scene
    source = copy.deepcopy(scene.source)
    source["fibers"].update(recipe or {})
    if index:
        source["fibers"].update(realisation_draw(scene, index, recipe))
    other = scene_from_dict(source, where=f"{scene.path or 'scene'} (realisation {index})")
    other.path = scene.path
    return other


def realisation_views(scenes, index: int, recipe: dict | None = None) -> list:
    """Realisation `index` of several views of the same strands (a target's scenes, whose [fibers] agree): the
    generator runs once and every view holds that one assembly, each with its own camera, lights and render
    settings, so the strands are checked once and `prepare_views` builds one BVH for them. A view whose [fibers]
    differs gets its own realisation."""
    scenes = list(scenes)
    if index == 0 and not recipe:
        return scenes
    first = realisation(scenes[0], index, recipe)
    views = [first]
    for scene in scenes[1:]:
        if scene.source.get("fibers") != scenes[0].source.get("fibers"):
            views.append(realisation(scene, index, recipe))
            continue
        source = copy.deepcopy(scene.source)
        source["fibers"] = copy.deepcopy(first.source["fibers"])
        view = dataclasses.replace(scene, fibers=first.fibers, source=source)
        check_scene(view)  # its camera's scale and buffers; the strands' interpenetration is checked once an assembly
        views.append(view)
    return views
