"""warp-hair: the Chiang et al. hair/fur BSDF in NVIDIA Warp, for rendering and fitting fiber swatches."""

import warp as wp

# Warp logs every module load at INFO; users want warnings and errors only.
wp.config.log_level = wp.LOG_WARNING

from . import bsdf  # noqa: E402
from .params import HairParams  # noqa: E402

__all__ = ["HairParams", "bsdf"]
__version__ = "0.1.0"
