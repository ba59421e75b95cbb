"""Cubic curves in their textbook forms (Bernstein, uniform B-spline blending functions, Catmull-Rom as Hermite),
written independently of warp_hair.geometry.curves' basis matrices, and a point-to-polyline distance."""

import numpy as np

from warp_hair.geometry.curves import span_count


def bezier(p, t):
    u = 1 - t
    return u**3 * p[0] + 3 * u**2 * t * p[1] + 3 * u * t**2 * p[2] + t**3 * p[3]


def bspline(p, t):
    b = [(1 - t) ** 3 / 6, (3 * t**3 - 6 * t**2 + 4) / 6, (-3 * t**3 + 3 * t**2 + 3 * t + 1) / 6, t**3 / 6]
    return sum(w * q for w, q in zip(b, p))


def hermite_catmull_rom(p, t):
    m1, m2 = (p[2] - p[0]) / 2, (p[3] - p[1]) / 2
    h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
    return h00 * p[1] + h10 * m1 + h01 * p[2] + h11 * m2


FORMS = {"bezier": (bezier, 3), "bspline": (bspline, 1), "catmullRom": (hermite_catmull_rom, 1)}


def dense_curve(cv, basis, per_span=400):
    form, step = FORMS[basis]
    spans = span_count(basis, "nonperiodic", len(cv))
    t = np.linspace(0.0, 1.0, per_span)[:, None]
    return np.concatenate([form(cv[s * step : s * step + 4], t) for s in range(spans)])


def distance_to_polyline(points, polyline):
    """Each point's distance to the nearest segment of `polyline`."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.clip(np.einsum("psk,sk->ps", points[:, None, :] - a[None], ab) / np.einsum("sk,sk->s", ab, ab), 0, 1)
    nearest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)
