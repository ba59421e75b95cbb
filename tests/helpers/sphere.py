"""Directions and quadrature on the unit sphere for the BSDF tests.

The sphere is parametrised by (z = sin θ, φ) with sin θ = w.x: dω = d(sin θ) dφ, so a grid uniform in
(sin θ, φ) has cells of equal solid angle (Archimedes).
"""

import numpy as np


def direction(sin_theta, phi):
    """Unit vectors of the local frame (x along the fiber) from sin θ and φ = atan2(z, y)."""
    sin_theta = np.asarray(sin_theta, dtype=np.float64)
    cos_theta = np.sqrt(np.maximum(0.0, 1.0 - sin_theta**2))
    return np.stack([sin_theta, cos_theta * np.cos(phi), cos_theta * np.sin(phi)], axis=-1)


def from_angles(theta_deg, phi_deg):
    return direction(np.sin(np.radians(theta_deg)), np.radians(phi_deg))


def random_directions(rng, n):
    return direction(rng.uniform(-1.0, 1.0, n), rng.uniform(-np.pi, np.pi, n))


def stratified_directions(rng, n_z, n_phi):
    """One jittered direction in each of n_z × n_phi equal-area cells; each carries solid angle 4π/(n_z n_phi)."""
    iz, ip = np.meshgrid(np.arange(n_z), np.arange(n_phi), indexing="ij")
    z = -1.0 + 2.0 * (iz.ravel() + rng.random(iz.size)) / n_z
    phi = -np.pi + 2.0 * np.pi * (ip.ravel() + rng.random(ip.size)) / n_phi
    return direction(z, phi)


def midpoint_grid(n_z, n_phi):
    """Cell centres of an n_z × n_phi equal-area grid (row-major in z), and the solid angle of one cell."""
    z = -1.0 + (np.arange(n_z) + 0.5) * 2.0 / n_z
    phi = -np.pi + (np.arange(n_phi) + 0.5) * 2.0 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    return direction(zz.ravel(), pp.ravel()), 4.0 * np.pi / (n_z * n_phi)
