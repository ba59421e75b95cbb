"""The limits on what reaches the kernels, and the small checks that enforce them.

The kernels compute in float32 and index with int32, so a value that is a fine Python float or int can still
overflow, underflow or wrap there and give a black or NaN image without a word. Every boundary where user
values become kernel values (scene tables, fiber data, hair controls, camera frames, render settings, the
command line) checks them here, and a value beyond these limits is an error naming it:

- lengths (fiber coordinates and radii, camera positions, the orthographic width, the card distance): at most
  LENGTH_LIMIT = 1e15 in magnitude, radii and widths at least LENGTH_MIN = 1e-15, so that squares and the
  ray-tube quadratic stay normal float32 numbers;
- the scene's extent (the largest coordinate magnitude of the fibers and the camera) at most RESOLUTION_LIMIT
  = 3e4 times the smallest fiber radius: float32 resolves a position to 6e-8 of its magnitude, and the ray-tube
  test loses the fiber's edges as that nears the radius (benchmarks/float32_scale.py: a swatch moved to 2.5e4
  radii from the origin renders 1.4% darker, at 1e5 radii 4.5%);
- radiance and irradiance (a constant, or an environment image times its scale): at most RADIANCE_LIMIT =
  1e12, which leaves room for the BSDF's peaks and the squares of the per-pixel error estimate;
- counts (resolution, spp, max_depth, rr_depth, strands, vertices): int32; seeds below 2**32;
- sizes that allocate (generated fibers, image buffers) are compared with the memory available before any
  allocation, and an error says how much they would take.

Numbers are strict: a bool or a string is not a number, even where Python would convert it.
"""

from __future__ import annotations

import math
import numbers
import os

import numpy as np

LENGTH_LIMIT = 1e15
LENGTH_MIN = 1e-15
RESOLUTION_LIMIT = 3e4
RADIANCE_LIMIT = 1e12
INT32_MAX = 2**31 - 1
# Warp's random streams are seeded with a uint32.
SEED_LIMIT = 2**32


def is_number(value) -> bool:
    """A real number: int, float or a NumPy scalar, but not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def real(name, value) -> float:
    """`value` as a finite float, or a ValueError naming `name` (a bool or a string is not a number)."""
    if not is_number(value):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        x = float(value)
    except OverflowError:  # an int beyond float range
        raise ValueError(f"{name} must be finite, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def integer(name, value, minimum=None, maximum=INT32_MAX) -> int:
    """`value` as an int in [minimum, maximum] (default: what an int32 holds), or a ValueError naming `name`."""
    if not isinstance(value, numbers.Integral) or isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be at most {maximum}, got {value!r}")
    return value


def seed(name, value) -> int:
    return integer(name, value, minimum=0, maximum=SEED_LIMIT - 1)


def length(name, value, positive=False) -> float:
    """A length in scene units: |value| ≤ LENGTH_LIMIT, and ≥ LENGTH_MIN when `positive`."""
    x = real(name, value)
    if positive and not LENGTH_MIN <= x <= LENGTH_LIMIT:
        raise ValueError(f"{name} must be in [{LENGTH_MIN:g}, {LENGTH_LIMIT:g}] scene units, got {x!r}")
    if abs(x) > LENGTH_LIMIT:
        raise ValueError(f"{name} must be at most {LENGTH_LIMIT:g} in magnitude, got {x!r}")
    return x


def position(name, value) -> tuple:
    """Three numbers, each a length (|x| ≤ LENGTH_LIMIT)."""
    return tuple(length(name, v) for v in triple(name, value))


def triple(name, value) -> tuple:
    """Three finite floats."""
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != 3 or not all(is_number(v) for v in value):
        raise ValueError(f"{name} must be three numbers, got {value!r}")
    if not all(math.isfinite(v) for v in value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return tuple(float(v) for v in value)


def unit(name, value) -> np.ndarray:
    """The unit vector along three numbers, float64 (3,): scaled by its largest component first, so that
    neither tiny (1e-320) nor huge (1e308) components underflow or overflow on the way."""
    v = np.array(triple(name, value))
    largest = np.abs(v).max()
    if largest == 0.0:
        raise ValueError(f"{name} must be a nonzero vector, got {list(value)}")
    v = v / largest
    v /= np.linalg.norm(v)
    return v


def radiance(name, value) -> tuple:
    """An RGB radiance or irradiance: three numbers in [0, RADIANCE_LIMIT]."""
    rgb = triple(name, value)
    if not all(0.0 <= c <= RADIANCE_LIMIT for c in rgb):
        raise ValueError(f"{name} must be three numbers in [0, {RADIANCE_LIMIT:g}], got {value!r}")
    return rgb


def radiance_image(name, image) -> None:
    """An (H, W, 3) radiance image (already scaled): finite, ≥ 0 and at most RADIANCE_LIMIT."""
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(image) | (image < 0) | (image > RADIANCE_LIMIT)
    if bad.any():
        y, x, c = np.argwhere(bad)[0]
        raise ValueError(
            f"{name}: radiance must be finite and in [0, {RADIANCE_LIMIT:g}], got {image[y, x, c]} at pixel "
            f"(x={x}, y={y}), channel {'RGB'[c]}"
        )


def fiber_values(points, radii):
    """(row, problem) of the first vertex whose position or radius is beyond the length limits, else None."""
    with np.errstate(invalid="ignore"):
        far = np.flatnonzero((np.abs(points) > LENGTH_LIMIT).any(axis=1))
        thin = np.flatnonzero((radii < LENGTH_MIN) | (radii > LENGTH_LIMIT))
    if far.size and (not thin.size or far[0] <= thin[0]):
        v = int(far[0])
        return v, f"position ({', '.join(map(str, points[v]))}) is beyond ±{LENGTH_LIMIT:g}"
    if thin.size:
        v = int(thin[0])
        return v, f"radius {radii[v]!s} is outside [{LENGTH_MIN:g}, {LENGTH_LIMIT:g}]"
    return None


def scene_scale(fibers, camera) -> None:
    """The extent of fibers and camera against the thinnest fiber: float32 must resolve its radius."""
    if fibers.num_vertices == 0:
        return
    extent = max(float(np.abs(fibers.points).max()), *(abs(c) for c in camera.origin + camera.target))
    thinnest = float(fibers.radii.min())
    if extent > RESOLUTION_LIMIT * thinnest:
        raise ValueError(
            f"the fibers and camera extend to {extent:.3g} scene units from the origin, {extent / thinnest:.3g} times "
            f"its "
            f"thinnest fiber radius {thinnest:.3g}; float32 resolves positions to 6e-8 of their size, so keep "
            f"that ratio below {RESOLUTION_LIMIT:g} (centre the fibers and the camera near the origin, or "
            "scale the scene)"
        )


# Peak bytes per fiber segment of preparing a scene (the BVH build; tracemalloc, 420 000 segments: 1.0-1.5 KB),
# and per pixel of a render's buffers (image and error estimate, in Warp and as NumPy copies).
PREPARE_BYTES_PER_SEGMENT = 1600
RENDER_BYTES_PER_PIXEL = 96


def render_memory(segments: int, resolution) -> None:
    """Raise before a render whose scene preparation and image buffers would not fit in memory."""
    width, height = resolution
    memory(
        f"rendering {segments} fiber segments at {width}x{height}",
        segments * PREPARE_BYTES_PER_SEGMENT + width * height * RENDER_BYTES_PER_PIXEL,
    )


def format_bytes(size: float) -> str:
    for unit_name in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if size < 1024 or unit_name == "PiB":
            return f"{size:.3g} {unit_name}"
        size /= 1024
    return f"{size:.3g} EiB"


def available_memory() -> int:
    """Bytes this process can still allocate: the machine's available memory, and the address-space limit
    (`ulimit -v`) minus what the process already maps."""
    available = None
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    available = int(line.split()[1]) * 1024
    except OSError:
        pass
    if available is None:
        try:
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            available = 2**63
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            with open("/proc/self/statm") as statm:
                mapped = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
            available = min(available, max(0, soft - mapped))
    except (ImportError, OSError, ValueError):
        pass
    return available


def memory(what: str, size: float) -> None:
    """Raise a MemoryError-free ValueError when `size` bytes for `what` exceed the memory available."""
    free = available_memory()
    if size > free:
        raise ValueError(
            f"{what} would take {format_bytes(size)} of memory, more than the {format_bytes(free)} available"
        )
