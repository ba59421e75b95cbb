"""How much less Monte Carlo noise a Gauss–Newton step would carry at the same samples, were each loss block's (or
each image's) samples allotted by its share of the step's noise rather than evenly (issue 45, goal 2).

    python benchmarks/sample_allocation.py [NAME ...] [--spp 64] [--oracle-spp 1024]

A step's end point moves with the noise of the gradient Aᵀ W r̄ (optimize/linearize.py): block b of an image adds
q_b / s_b to its variance, measured along every control alike (the trace of H⁻¹ D H⁻¹ against the block's
per-sample noise covariance, D normalising each control by the step's own variance), where s_b is the block's
samples per pixel. For a fixed total, Σ q_b / s_b is least at s_b ∝ √q_b (Neyman's allocation), and the gain against
even samples is n Σ q_b / (Σ √q_b)². A block's q_b is taken from a linearisation's pooled Jacobian and Monte Carlo
variances, weighted as the loss weighs them (`linearize`; channels independent: an approximation, they share their
paths). It
counts the residuals' noise only, not the Jacobians' noise times the residuals that `Linearization.gradient_covariance`
also counts. Photo targets are left out: their renders are scaled by gains this script does not fit. Printed per
target, at the truth:

- the gain were the allotment made from accurate q_b (a linearisation at --oracle-spp: what no fit knows),
- the gain of an allotment made from one linearisation at --spp (what a fit would know), each
  block at least 2 samples a pixel (a pixel's standard error needs two), measured against the accurate q_b,
- the same with one sample count per image (its blocks' summed q), and each image's share of the step's variance.

It assumes every sample costs the same; a block of background costs less than one of hair. Nothing here is used by
the fit: it measures a lever (docs/benchmarks.md, issue 45).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import warnings

import numpy as np

from optimize import camera, load_target
from optimize.linearize import inverse_curvature, linearize
from optimize.settings import FitSettings
from optimize.target import SHIPPED_TARGETS
from warp_hair.renderer.prepare import prepare

MIN_SAMPLES = 2  # a pixel's standard error needs two samples


def block_noise(lin, metric, spp: int) -> list:
    """Per image, each loss block's q_b: its share of the step's variance per sample a pixel, from a linearisation's
    own weighted, pooled Jacobians and Monte Carlo variances (`linearize` weighs them as the loss does)."""
    a = lin.mean_jacobian * lin.loss_weights[:, None]
    per_sample = lin.variances.mean(axis=0) * spp
    q = np.einsum("np,n,nq,qp->n", a, per_sample, a, metric).reshape(-1, 3).sum(axis=1)
    bounds = np.cumsum((0, *lin.image_residuals)) // 3
    return [np.maximum(q[b0:b1], 0.0) for b0, b1 in itertools.pairwise(bounds)]


def gain(q: np.ndarray, samples: np.ndarray) -> float:
    """Even samples' variance Σ q / 1 over the allotment's Σ q / s (s of mean 1)."""
    return float(q.sum() / (q / (samples / samples.mean())).sum())


def allotted(estimate: np.ndarray, spp: int) -> np.ndarray:
    s = np.sqrt(estimate)
    s = s / max(s.mean(), 1e-300)
    return np.maximum(s, MIN_SAMPLES / spp)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", default=["black_straight", "brown_wavy", "blonde_straight", "fur_patch"])
    parser.add_argument("--spp", type=int, default=64, help="a linearisation's samples a pass (the fit's 4 × 16)")
    parser.add_argument("--oracle-spp", type=int, default=1024, help="the accurate render's samples")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    header = ("target", "images", "gain, accurate allotment", "gain, from one linearisation", "one count per image")
    print("| " + " | ".join(header) + " | images' shares |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for name in args.names:
        target = load_target(SHIPPED_TARGETS / name)
        if camera.fitted(target):
            print(f"{name}: left out, a photo target (its gains are not fitted here)", file=sys.stderr)
            continue
        truth = json.loads((SHIPPED_TARGETS / name / "truth.json").read_text())
        values = {n: truth[n] for n in FitSettings().controls if n in truth}
        scenes = [prepare(image.scene) for image in target.images]
        lin = linearize(target, values, FitSettings(), args.spp, 1234, scenes=scenes)
        h_inv = inverse_curvature(lin.curvature)
        metric = h_inv @ np.diag(1.0 / np.diag(lin.step_covariance)) @ h_inv
        oracle = linearize(target, values, FitSettings(), args.oracle_spp, 77, scenes=scenes)
        accurate = block_noise(oracle, metric, args.oracle_spp)
        noisy = block_noise(lin, metric, args.spp)
        q, q_noisy = np.concatenate(accurate), np.concatenate(noisy)
        per_image = np.concatenate([np.full(b.size, np.sqrt(b.mean())) for b in noisy])
        shares = ", ".join(f"{float(b.sum() / q.sum()):.3f}" for b in accurate)
        print(
            f"| {name} | {len(accurate)} | {gain(q, allotted(q, args.spp)):.2f} | "
            f"{gain(q, allotted(q_noisy, args.spp)):.2f} | {gain(q, per_image):.2f} | {shares} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
