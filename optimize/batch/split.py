"""A render split across workers, bit for bit the render one machine makes.

Every pixel draws its paths from its own random stream, seeded by (seed, pixel index) alone
(`warp_hair.renderer.render.pixel_start`: `wp.rand_init(seed, pixel)`), and `render(..., pixels=idx)` traces
each listed pixel exactly as it is traced in the whole image. So a part of the image is a set of pixel indices:
the parts are rendered anywhere, in any order, with any number of threads, and put back by index; no pixel
depends on which part it is in. The parts deal out ranges of RANGE pixels in turn (part k takes ranges k, k + n,
...), so that each part gets its share of the expensive fiber pixels wherever they lie in the frame.
"""

from __future__ import annotations

import numpy as np

# Pixels per range dealt to a part: the renderer's own tile size, small against any image worth splitting.
RANGE = 256


def part_pixels(resolution, part: int, parts: int) -> np.ndarray:
    """The flat pixel indices (row · width + column) of part `part` of `parts`, ascending."""
    width, height = resolution
    index = np.arange(width * height, dtype=np.int64)
    return index[(index // RANGE) % parts == part].astype(np.int32)


def assemble(resolution, pieces) -> tuple:
    """(image, stderr), each (H, W, 3) float32, from `pieces`: (pixels, image values (n, 3), stderr (n, 3)) of
    every part. A ValueError if the parts do not cover every pixel exactly once."""
    width, height = resolution
    image = np.zeros((width * height, 3), np.float32)
    stderr = np.zeros((width * height, 3), np.float32)
    count = np.zeros(width * height, np.int64)
    for pixels, values, errors in pieces:
        image[pixels] = values
        stderr[pixels] = errors
        np.add.at(count, pixels, 1)
    if not np.all(count == 1):
        raise ValueError(
            f"the render's parts cover {int(np.sum(count > 0))} of {count.size} pixels "
            f"({int(np.sum(count > 1))} more than once): they are not parts of one split"
        )
    return image.reshape(height, width, 3), stderr.reshape(height, width, 3)
