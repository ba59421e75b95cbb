"""Fiber geometry: strands as polylines with a radius per vertex, their files and generators, and the ray queries.

    assembly = warp_hair.geometry.swatch(count=200, seed=1)        # or wavy, curly, fur; or
    assembly = warp_hair.geometry.load_fibers("groom.hair")         # .hair, .txt, .usd/.usda/.usdc
    warp_hair.geometry.save_fibers(assembly, "swatch.txt")

Every strand is listed root first, in files (as `.hair`, Mitsuba's curve text and USD BasisCurves list them) and
in the generators: the cuticle tilt α shifts the primary highlight toward a strand's first vertex, so a strand
listed tip first would show it on the wrong side.

assembly.py holds `FiberAssembly`, formats.py and usd.py the files, generators.py the procedural swatches and
fur, curves.py cubic curves (Catmull-Rom through a strand's vertices, USD's bases) as polylines within a stated
distance; bvh.py builds the BVH, tubes.py the tubes it bounds, intersect.py the device ray queries, rays.py their
NumPy front, card.py the backing card; interpenetration.py counts the strands that pass through each other.
"""

from .assembly import FiberAssembly, FiberDataError
from .curves import catmull_rom
from .formats import load_fibers, read_hair, read_text, save_fibers, write_hair, write_text
from .generators import curly, fur, swatch, wavy

__all__ = [
    "FiberAssembly",
    "FiberDataError",
    "catmull_rom",
    "curly",
    "fur",
    "load_fibers",
    "read_hair",
    "read_text",
    "save_fibers",
    "swatch",
    "wavy",
    "write_hair",
    "write_text",
]
