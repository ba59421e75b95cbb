"""The variation's gradients at full path depth, in expectation: the image mean's derivative from the Jacobian
against central differences of independent high-spp renders.

    python benchmarks/variation_gradients.py [--scene TOML] [--spp 512] [--step 0.15] [--threads N]

Defaults to targets/brown_wavy/scene_back.toml at 24×24 with every variation control set (color_spread 0.4,
roughness_spread 0.3, tip_absorption 0.4, tip_length 0.6). tests/test_variation.py checks every column pixel by
pixel on one-bounce paths; this checks that the multi-bounce estimator, whose sampling depends on the controls,
agrees in the mean. Prints per control and channel the Jacobian's image mean (over 8 seeds of spp/8) and the
difference quotient, each with its standard error (the quotient's from the renders' per-pixel standard errors,
the two renders independent), and their difference in units of the two together (z).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from warp_hair.controls import column
from warp_hair.renderer.gradients import render_jacobian
from warp_hair.renderer.prepare import prepare
from warp_hair.renderer.render import render
from warp_hair.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
VARIATION = {"color_spread": 0.4, "roughness_spread": 0.3, "tip_absorption": 0.4, "tip_length": 0.6}
CONTROLS = ("color_spread", "roughness_spread", "tip_absorption", "tip_length")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default=str(ROOT / "targets" / "brown_wavy" / "scene_back.toml"))
    parser.add_argument("--spp", type=int, default=512)
    parser.add_argument("--step", type=float, default=0.15)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()

    scene = load_scene(args.scene)
    camera = dataclasses.replace(scene.camera, resolution=(24, 24))
    scene = dataclasses.replace(scene, camera=camera, hair=scene.hair.replace(**VARIATION))
    prepared = prepare(scene)
    # The Jacobian's image mean over 8 seeds of spp/8 each: their spread gives its standard error.
    means = [
        render_jacobian(prepared, spp=max(1, args.spp // 8), seed=20 + k, threads=args.threads)[0].mean(axis=(0, 1))
        for k in range(8)
    ]
    jacobian, jacobian_se = np.mean(means, axis=0), np.std(means, axis=0, ddof=1) / np.sqrt(len(means))
    print(f"{Path(args.scene).name} at 24x24, {args.spp} spp, step {args.step}: image mean's derivative per channel")
    print(f"{'control':<18} {'Jacobian':>22} {'s.e.':>20} {'difference quotient':>22} {'s.e.':>20}  z")
    for name in CONTROLS:
        value = getattr(scene.hair, name)

        def at(delta, seed, name=name, value=value):
            hair = scene.hair.replace(**{name: value + delta})
            return render(prepared.with_hair(hair), spp=args.spp, seed=seed, threads=args.threads, return_stderr=True)

        (plus, plus_se), (minus, minus_se) = at(args.step, 11), at(-args.step, 12)
        pixels = plus.shape[0] * plus.shape[1]
        quotient = (plus - minus).mean(axis=(0, 1)) / (2 * args.step)
        error = np.sqrt((plus_se**2 + minus_se**2).sum(axis=(0, 1))) / pixels / (2 * args.step)
        analytic, analytic_se = jacobian[:, column(name)], jacobian_se[:, column(name)]
        z = (analytic - quotient) / np.sqrt(analytic_se**2 + error**2)

        def shown(values, sign="+"):
            return " ".join(f"{x:{sign}.4f}" for x in values)

        print(
            f"{name:<18} {shown(analytic):>22} {shown(analytic_se, ''):>20} {shown(quotient):>22} "
            f"{shown(error, ''):>20}  {shown(z)}"
        )


if __name__ == "__main__":
    main()
