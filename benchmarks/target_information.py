"""What a target's images can tell a fit, and what more would take: `warp-hair targets check` on variants.

    python benchmarks/target_information.py [NAME ...] [--views side,sky] [--threads N]

For each named target (default: blonde_straight, cycles_blonde_straight, mitsuba_blonde_straight) runs
`optimize.identify.check_target` on the target as shipped and with extra views added, each fitting albedo, β_m,
β_n and then exposure as well, and prints a Markdown table of red albedo's expected σ: the target's own noise at
its spp, its shift were the target 1% brighter, the two together with the model error the fit counts (0 for
warp-hair's targets, 1% for others), the factor on the target's samples that would bring it within the bound
(σ_noise falls as 1/√spp, the model part does not), and the β's shifts.

An extra view is a copy of the target's first scene under another light (`side`: a directional light from the
side, grazing the swatch; `sky`: a uniform white sky alone), at the target's spp; its image is rendered by
warp-hair at VIEW_SPP, which is all the check takes of it (the loss's weight for the image: the noise and the
shifts come from our renders at the true controls), so for a peer's target it stands for that renderer's image.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

import numpy as np
import tomlkit

from optimize.identify import check_target
from optimize.settings import ALBEDO_BOUND
from optimize.target import TARGET_FILE, load_target
from targets import path as shipped_path
from warp_hair.cli import exit_on_interrupt
from warp_hair.io import write_exr
from warp_hair.renderer.render import render, render_metadata
from warp_hair.scene import load_scene

DEFAULT_TARGETS = ("blonde_straight", "cycles_blonde_straight", "mitsuba_blonde_straight")
VIEWS = {
    "side": [{"type": "directional", "direction": [-1.0, -0.2, -0.3], "irradiance": [3.0, 3.0, 3.0]}],
    "sky": [{"type": "environment", "radiance": [1.0, 1.0, 1.0]}],
}
VIEW_SPP = 256
FITS = (("albedo", "beta_m", "beta_n"), ("albedo", "beta_m", "beta_n", "exposure"))


def with_views(source: Path, views, directory: Path, threads) -> Path:
    """A copy of the target at `source` with one image per extra view."""
    shutil.copytree(source, directory)
    spec = tomlkit.parse((directory / TARGET_FILE).read_text(encoding="utf-8"))
    first = spec["images"][0]["scene"]
    for view in views:
        data = tomlkit.parse((directory / first).read_text(encoding="utf-8"))
        data["lights"] = tomlkit.item(VIEWS[view])
        (directory / f"scene_{view}.toml").write_text(tomlkit.dumps(data), encoding="utf-8")
        scene = load_scene(directory / f"scene_{view}.toml")
        write_exr(
            directory / f"{view}.exr",
            render(scene, spp=VIEW_SPP, seed=7, threads=threads),
            render_metadata(scene, VIEW_SPP, 7),
        )
        spec["images"].append({"scene": f"scene_{view}.toml", "image": f"{view}.exr"})
    (directory / TARGET_FILE).write_text(tomlkit.dumps(spec), encoding="utf-8")
    return directory


def row(name, views, result) -> str:
    k = result.labels.index("albedo[r]")
    model = result.model_error / 0.01 * abs(result.shift[k])
    if model >= ALBEDO_BOUND:
        takes = "no number of samples"
    else:
        factor = result.noise[k] ** 2 / (ALBEDO_BOUND**2 - model**2)
        takes = (
            "as it is"
            if factor <= 1
            else f"{factor:.2g}× the samples ({int(np.ceil(factor * max(result.target_spp)))} spp)"
        )
    betas = " / ".join(f"{result.shift[result.labels.index(b)]:+.4f}" for b in ("beta_m", "beta_n"))
    fitted = "+ exposure" if "exposure" in result.values else "albedo, β_m, β_n"
    return (
        f"| {name} | {', '.join(['front', 'back', *list(views)])} | {fitted} | {max(result.target_spp)} "
        f"| {result.noise[k]:.4f} | {result.shift[k]:+.4f} | {betas} | {result.sigma[k]:.4f} | {takes} "
        f"| {'yes' if result.identifiable else 'no'} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", default=list(DEFAULT_TARGETS))
    parser.add_argument("--views", default="side,sky", help="extra views, added one after another (default side,sky)")
    parser.add_argument("--threads", type=int)
    args = parser.parse_args()
    extra = [v for v in args.views.split(",") if v]
    unknown = sorted(set(extra) - set(VIEWS))
    if unknown:
        raise SystemExit(f"unknown view(s) {unknown}; allowed: {sorted(VIEWS)}")
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.names:
            for n in range(len(extra) + 1):
                views = extra[:n]
                directory = with_views(shipped_path(name), views, Path(scratch) / f"{name}_{n}", args.threads)
                target = load_target(directory)
                for controls in FITS:
                    rows.append(row(name, views, check_target(target, controls=controls, threads=args.threads)))
                    print(rows[-1], flush=True)
    print()
    print(
        "| target | views | fitted | spp | σ noise, albedo[r] | shift per 1% brighter, albedo[r] | β_m / β_n "
        "| σ expected, albedo[r] | to meet 0.02 | identifiable |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))


if __name__ == "__main__":
    exit_on_interrupt(main)
