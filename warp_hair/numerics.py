"""Constants shared by the model, the geometry and the renderer, each defined once.

Warp constants are folded into the kernels that use them; the float32 ones round the exact value once.
"""

import math

import warp as wp

PI = wp.constant(math.pi)
TWO_PI = wp.constant(2.0 * math.pi)
INV_PI = wp.constant(1.0 / math.pi)
INV_TWO_PI = wp.constant(1.0 / (2.0 * math.pi))
INV_FOUR_PI = wp.constant(1.0 / (4.0 * math.pi))
# In float64, for the steps the model takes in double precision.
PI64 = wp.constant(wp.float64(math.pi))
TWO_PI64 = wp.constant(wp.float64(2.0 * math.pi))

# The smallest normal float32. A sampled direction whose density is below it carries no weight: the ratio S/pdf
# of two subnormals is off by up to a percent, and such a direction (the far tail of a very narrow lobe) is drawn
# with a probability near 1e-38.
FLOAT32_MIN_NORMAL = wp.constant(1.17549435e-38)

# The distance of "no hit" along a unit ray: beyond every scene (positions are at most 1e15 in magnitude).
NO_HIT = wp.constant(1.0e30)
