"""Fit a shipped target from the neutral guess and draw target | fit | difference for each of its images.

    python examples/fit_picture.py                      # brown_wavy → docs/fit.png (a few CPU minutes)
    python examples/fit_picture.py black_straight -o black.png

The fit is `warp-hair fit`'s, with its default settings: albedo, β_m and β_n from albedo 0.5 grey and
β_m = β_n = 0.5, Adam on two decorrelated renders per image and iteration, then Gauss–Newton steps. It prints
the fitted controls against the target's truth.json with each control's reported 1σ. The picture is the
fit's comparison.png (one row per image: the target, the fit, and fit − target in units of its noise σ on a
diverging scale), with the fitted look rendered at the target's own samples per pixel and another seed, so that
the difference shows the two renders' noise at the same level and any misfit above it (optimize/report.py).
"""

import argparse
from pathlib import Path

from optimize import fit, load_target
from optimize.report import describe_run, format_table, plot_comparison, render_pictures
from optimize.settings import FitSettings
from optimize.target import resolve_target, true_values
from warp_hair.cli import exit_on_interrupt

ROOT = Path(__file__).resolve().parent.parent


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("target", nargs="?", default="brown_wavy", help="a shipped target's name or a directory")
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "fit.png")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    target = load_target(resolve_target(args.target))
    settings = FitSettings(seed=args.seed, threads=args.threads)
    result = fit(target, settings)
    print(format_table(result, true_values(target, result.values)))
    print(f"{describe_run(result.iterations, result.stop_reason, result.history.refine)}, {result.seconds:.0f} s")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    plot_comparison(args.output, render_pictures(result, target, settings, progress=True))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    exit_on_interrupt(main)  # as the command: Warp's own messages left out, Ctrl-C one line
