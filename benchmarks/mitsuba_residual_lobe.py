"""Mitsuba 3's hair sampler against its own eval: the residual lobe's samples all leave in the normal plane.

    python benchmarks/mitsuba_residual_lobe.py [--samples 2000000]

For one light-brown look (σ_a = (0.05, 0.08, 0.15) per radius, β_m 0.3, β_n 0.35, α 0) and several incident
directions (θ, h), it estimates two integrals of the cosine-weighted BSDF S over the sphere of scattered
directions: ∫ S dω (the fiber's directional albedo) and ∫ S sin²θ dω (how much of it leaves along the fiber
rather than across it). Each is computed three ways: by quadrature of Mitsuba's own `eval` on a fine grid, as
the mean of Mitsuba's `sample` weights (times sin²θ), and the same with the residual lobe corrected
(`mitsuba_peer.CorrectedHair`); warp-hair's `bsdf.sample` gives a fourth. An unbiased sampler matches the
quadrature within its standard error in both. Mitsuba's matches ∫ S dω (its weights are eval/pdf) but not
∫ S sin²θ dω: `Hair::sample` leaves sin θ of the residual lobe (p = 3) at 0, and the bias grows toward
grazing incidence, where the residual lobe carries the most. It also prints the share of Mitsuba's samples with
sin θ exactly 0 next to the residual lobe's sampling probability. The `bench` extra and libLLVM are needed.
"""

from __future__ import annotations

import argparse

import numpy as np
from mitsuba_peer import corrected_hair, import_mitsuba

import warp_hair as wh
from warp_hair.export.mitsuba import bsdf_dict

LOOK = {"sigma_a": [0.05, 0.08, 0.15], "beta_m": 0.3, "beta_n": 0.35, "alpha": 0.0}
CASES = [(0.0, 0.0), (20.0, 0.5), (40.0, 0.9), (60.0, 0.95), (75.0, -0.98)]
GRID = 1200  # quadrature cells along sin θ and along φ


def mitsuba_wi(theta, h):
    """Mitsuba's local frame: y along the fiber, z the normal; `si.wi` points to the viewer (our wo)."""
    t, g = np.radians(theta), np.arcsin(h)
    return np.array([-np.cos(t) * np.sin(g), np.sin(t), np.cos(t) * np.cos(g)])


def ours_wo(theta, h):
    """Ours (docs/MODEL.md): x along the fiber, z the normal, φ = atan2(z, y) and h = −cos φ."""
    t, phi = np.radians(theta), np.arccos(-h)
    return np.array([np.sin(t), np.cos(t) * np.cos(phi), np.cos(t) * np.sin(phi)])


def grid(along):
    """Equal-area cell centres (sin θ along axis `along`) and the solid angle of one cell."""
    z = -1.0 + (np.arange(GRID) + 0.5) * 2.0 / GRID
    phi = (np.arange(GRID) + 0.5) * 2.0 * np.pi / GRID
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    c = np.sqrt(1.0 - zz**2)
    across = [c * np.cos(pp), c * np.sin(pp)]
    axes = [*across[:along], zz, *across[along:]]
    return np.stack([a.ravel() for a in axes], axis=-1), 4.0 * np.pi / GRID**2


def mean_and_error(x):
    x = np.asarray(x, dtype=np.float64)  # float32 sums of millions of samples drift by tenths of a percent
    return x.mean(axis=0), x.std(axis=0) / np.sqrt(len(x))


def fmt(mean, error=None):
    text = f"{mean.mean():.5f}"
    return text if error is None else f"{text} ± {error.mean():.5f}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=2_000_000)
    args = parser.parse_args(argv)
    mi = import_mitsuba()
    if mi is None:
        return 1
    import drjit as dr

    params = wh.HairParams(**LOOK)
    stock = mi.load_dict(bsdf_dict(params))
    corrected = mi.load_dict(corrected_hair(mi, bsdf_dict(params)))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(0)
    n = args.samples

    def interaction(wi, count):
        si = dr.zeros(mi.SurfaceInteraction3f, count)
        si.wi = mi.Vector3f(*[np.full(count, c, dtype=np.float32) for c in wi])
        return si

    def vectors(x):
        return mi.Vector3f(*[np.ascontiguousarray(x[:, k], dtype=np.float32) for k in range(3)])

    def rows(x):
        x = np.array(x)
        return x.T if x.shape[0] == 3 else x

    print(f"look {LOOK}; channel means; ± one standard error over {n} samples")
    print(
        "| θ (deg) | h | P(residual) | Mitsuba samples with sin θ = 0 | ∫S dω quadrature | Mitsuba | corrected | "
        "warp-hair | ∫S sin²θ dω quadrature | Mitsuba | corrected | warp-hair |"
    )
    print("| " + " | ".join(["---"] * 12) + " |")
    for theta, h in CASES:
        wi = mitsuba_wi(theta, h)
        directions, d_omega = grid(along=1)
        values = rows(stock.eval(ctx, interaction(wi, len(directions)), vectors(directions)))
        quad = values.sum(axis=0) * d_omega, (values * directions[:, 1:2] ** 2).sum(axis=0) * d_omega
        u = rng.random((n, 3), dtype=np.float32)  # in [0, 1) as float32, for both samplers
        estimates = {}
        for label, bsdf in (("stock", stock), ("corrected", corrected)):
            bs, weight = bsdf.sample(ctx, interaction(wi, n), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]))
            weight, out = rows(weight), rows(bs.wo)
            estimates[label] = (mean_and_error(weight), mean_and_error(weight * out[:, 1:2] ** 2))
            if label == "stock":
                flat = np.mean(out[:, 1] == 0.0)
        wo = ours_wo(theta, h)
        out, weight, _ = wh.bsdf.sample(params, wo, h, u)
        estimates["ours"] = (mean_and_error(weight), mean_and_error(weight * out[:, 0:1] ** 2))
        attenuation = wh.bsdf.attenuation(params, wo, h)[0]
        share = attenuation.mean(axis=1)  # the sampler picks lobes by the channel mean of A_p
        residual = share[3] / share.sum()
        cells = [f"{theta:g}", f"{h:g}", f"{residual:.4f}", f"{flat:.4f}", fmt(quad[0])]
        cells += [fmt(*estimates[k][0]) for k in ("stock", "corrected", "ours")]
        cells += [fmt(quad[1])] + [fmt(*estimates[k][1]) for k in ("stock", "corrected", "ours")]
        print("| " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
