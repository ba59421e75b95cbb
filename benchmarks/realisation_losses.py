"""Which loss depends least on where the target's strands lie (issue 23, section 1): the spread of the estimate
over the strands' draw, for the fit's loss and for the alternatives studied, linearised at the truth.

    python benchmarks/realisation_losses.py [NAME | DIR] [--jacobian-spp 256] [--jacobian-pairs 12]
        [--realisations 64] [--spp 128] [--threads N]

For a target (a shipped one's name, default cycles_dark_straight, or a target directory) at its true controls:
- A, the Jacobian of its images by the fitted controls: `--jacobian-pairs` linearisations over random pairs of
  realisations, two passes each at `--jacobian-spp`. A Jacobian of few passes inflates H = AᵀΩ²A along a weakly
  determined control and so shrinks every estimate, which looks like a small spread (docs/acceptance.md, "Weighing
  the residuals"); H is the crossed (unbiased) product of the passes.
- `--realisations` further realisations rendered at the truth (`--spp`): 16 give the realisation average Ī, 8
  more the relative weights' own average, the rest are held out as targets.

Each loss compares k_y × k_x block means with weights Ω (the fit's L2: each image by its own scale; relative:
1/(Ī + ε mean Ī) per block, Ī from the weights' realisations). A target T moves the estimate by
u = H⁻¹ AᵀΩ²(T − Ī). Printed per loss: the spread (standard deviation) of u over the held-out realisations, for
β_n, β_m and red albedo, and of β_n over the Cycles targets: the shipped one and any target draws under
benchmarks/out/realisations/target-draws/NAME/ (`realisation_acceptance.py --target-draws`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tqdm import tqdm

from optimize.fit import FitSettings
from optimize.latents import hair_and_gain
from optimize.linearize import linearize, loss_weights
from optimize.realisations import Realisations
from optimize.target import load_target, true_values
from warp_hair.cli import exit_on_interrupt
from warp_hair.renderer.render import render
from warp_hair.torch import scene_with_controls

HERE = Path(__file__).resolve().parent
NAMES = ["albedo", "beta_m", "beta_n"]  # fitted components: red, green, blue albedo, β_m, β_n
RED, BETA_M, BETA_N = 0, 3, 4
MEAN_COUNT, WEIGHT_COUNT = 16, 8  # realisations for Ī and for the relative weights; the rest are held out
FIRST_REALISATION = 1000  # their indices: clear of the fit's pool and of the target draws (101…)
# label, blocks (rows, columns), relative weights' ε (None: the fit's L2), the back-lit image's weight
LOSSES = (
    ("4×4 blocks, L2 (the fit's)", (4, 4), None, 1.0),
    ("4×4 blocks, relative ε 0.1", (4, 4), 0.1, 1.0),
    ("2×2 blocks, relative ε 0.1", (2, 2), 0.1, 1.0),
    ("single pixels, relative ε 0.01", (1, 1), 0.01, 1.0),
    ("single pixels, relative ε 0.1", (1, 1), 0.1, 1.0),
    ("rows, L2", (1, 0), None, 1.0),
    ("2×16 blocks, L2", (2, 16), None, 1.0),
    ("16×4 blocks, L2", (16, 4), None, 1.0),
    ("8×8 blocks, L2", (8, 8), None, 1.0),
    ("4×4 blocks, L2, back-lit ×0.1", (4, 4), None, 0.1),
    ("4×4 blocks, L2, back-lit ×4", (4, 4), None, 4.0),
)


def blocks(x: np.ndarray, shape) -> np.ndarray:
    """(..., images, H, W, C) → block means over (rows, columns) blocks (0 columns: whole rows), flattened per
    image: (..., images, blocks × C)."""
    *lead, n, h, w, c = x.shape
    ky, kx = shape[0], shape[1] or w
    return x.reshape(*lead, n, h // ky, ky, w // kx, kx, c).mean(axis=(-4, -2)).reshape(*lead, n, -1)


def fits(shape, images) -> bool:
    h, w = images.shape[-3:-1]
    return h % shape[0] == 0 and w % (shape[1] or w) == 0


def spreads(study: dict, shape, epsilon, back: float) -> dict:
    """The estimate's moves u for the held-out realisations and the Cycles targets under one loss."""
    jac = blocks(np.moveaxis(study["jacobians"], -1, 1), shape)  # (passes, p, images, blocks)
    models = blocks(study["renders"], shape)  # (realisations, images, blocks)
    mean, weighed = models[:MEAN_COUNT].mean(axis=0), models[MEAN_COUNT : MEAN_COUNT + WEIGHT_COUNT].mean(axis=0)
    if epsilon is None:
        omega = 1.0 / np.sqrt(np.mean(mean * mean, axis=1, keepdims=True)) * np.ones_like(mean)
    else:
        omega = 1.0 / (weighed + epsilon * weighed.mean(axis=1, keepdims=True))
    omega[1:] *= np.sqrt(back)  # the back-lit image (the second) weighed `back` times as much
    w2 = (omega * omega).reshape(-1)
    j = jac.reshape(*jac.shape[:2], -1).transpose(0, 2, 1)  # (passes, N, p)
    # The crossed product as linearize.crossed_curvature forms it, without its fallback to the mean Jacobian's
    # product where the crossed one is not positive definite: that fallback is the inflated H this measures against.
    n, total = len(j), j.sum(axis=0)
    crossed = (total.T @ (w2[:, None] * total) - np.einsum("kni,n,knj->ij", j, w2, j)) / (n * (n - 1))
    gain = np.linalg.solve(0.5 * (crossed + crossed.T), (total / n * w2[:, None]).T)
    held_out = models[MEAN_COUNT + WEIGHT_COUNT :].reshape(-1, mean.size)
    cycles = blocks(study["cycles"], shape).reshape(-1, mean.size)
    return {"held_out": (held_out - mean.reshape(-1)) @ gain.T, "cycles": (cycles - mean.reshape(-1)) @ gain.T}


def study(source: Path, jacobian_spp: int, jacobian_pairs: int, count: int, spp: int, threads) -> dict:
    """The renders every loss is judged on (see the module docstring)."""
    if count < MEAN_COUNT + WEIGHT_COUNT + 3:
        raise SystemExit(f"--realisations must be at least {MEAN_COUNT + WEIGHT_COUNT + 3}, got {count}")
    target = load_target(source)
    truth = true_values(target, NAMES)
    realisations = Realisations(target)
    scale = np.array([loss_weights(image.image, "l2").flat[0] for image in target.images])  # linearize's, pool 1
    shape = target.images[0].image.shape
    jacobians = []
    for k in tqdm(range(jacobian_pairs), desc="Jacobian", unit="pair"):
        seed = 7001 + 7919 * k
        lin = linearize(target, truth, FitSettings(pool=1), jacobian_spp, seed, threads, realisations.pair(seed))
        for half in lin.jacobians:  # (N, p) weighted: back to radiance per image
            jacobians.append(half.reshape(len(target.images), *shape, -1) / scale[:, None, None, None, None])
    hair, _ = hair_and_gain(truth)
    renders = []
    for k in tqdm(range(count), desc="realisations", unit="real"):
        scenes = realisations.scenes(FIRST_REALISATION + k)
        renders.append([render(scene_with_controls(s, hair), spp=spp, seed=31 + k, threads=threads) for s in scenes])
    draws = sorted((HERE / "out" / "realisations" / "target-draws" / source.name).glob("target*/rendered"))
    cycles = [target] + [load_target(path.parent) for path in draws]
    return {
        "jacobians": np.array(jacobians),  # (passes, images, H, W, 3, p)
        "renders": np.array(renders),  # (realisations, images, H, W, 3)
        "cycles": np.array([[image.image for image in t.images] for t in cycles]),
        "cycles_names": ["shipped"] + [path.parent.name for path in draws],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "name", nargs="?", default="cycles_dark_straight", help="a shipped target's name or a target directory"
    )
    parser.add_argument("--jacobian-spp", type=int, default=256)
    parser.add_argument("--jacobian-pairs", type=int, default=12)
    parser.add_argument("--realisations", type=int, default=64)
    parser.add_argument("--spp", type=int, default=128, help="samples per pixel of each realisation's render")
    parser.add_argument("--threads", type=int)
    args = parser.parse_args()
    source = Path(args.name) if Path(args.name).is_dir() else HERE.parent / "targets" / args.name
    if not source.is_dir():
        parser.error(f"no shipped target {args.name!r} (targets/{args.name} does not exist) and no such directory")
    data = study(source, args.jacobian_spp, args.jacobian_pairs, args.realisations, args.spp, args.threads)
    held = args.realisations - MEAN_COUNT - WEIGHT_COUNT
    print(f"\n{args.name}: spread (standard deviation) of the estimate over {held} held-out realisations and over "
          f"{len(data['cycles_names'])} Cycles targets ({', '.join(data['cycles_names'])})\n")  # fmt: skip
    print("| loss | β_n, held out | β_m, held out | red albedo, held out | β_n, Cycles targets | shipped target |")
    print("| --- | --- | --- | --- | --- | --- |")
    for label, shape, epsilon, back in LOSSES:
        if not fits(shape, data["renders"]):
            continue
        u = spreads(data, shape, epsilon, back)
        held_out, cycles = u["held_out"].std(axis=0, ddof=1), u["cycles"][:, BETA_N]
        spread = f"{cycles.std(ddof=1):.4f}" if len(cycles) > 2 else "–"
        print(f"| {label} | {held_out[BETA_N]:.4f} | {held_out[BETA_M]:.4f} | {held_out[RED]:.4f} | {spread} | "
              f"{cycles[0]:+.4f} |")  # fmt: skip


if __name__ == "__main__":
    exit_on_interrupt(main)
