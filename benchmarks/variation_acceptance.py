"""Acceptance of hair as it grows (issue 44, item 5): targets whose strands vary, fitted with the variation's controls
and with a uniform look.

    python benchmarks/variation_acceptance.py [NAME ...] [--out benchmarks/out/variation] [--threads N] [--table]
    python benchmarks/variation_acceptance.py --check SPP [NAME ...]      # warp-hair at the truth against each image

The targets (default: all five): Cycles' own Random Color and Random Roughness on its melanin (dark, medium and
light hair; `cycles_varied_*`, rendered by `benchmarks/make_peer_targets.py` from each target's cycles_hair.toml)
and warp-hair's root-to-tip change (`brown_light_tips`, `auburn_light_tips_varied`, `warp-hair targets make`).
Each is fitted twice by `warp-hair fit` (run as a command, so this is the code a user runs, exit status included),
from its neutral start, at the default settings:

- "variation": the default controls (the colour and β_m, β_n) plus the variation's controls the target's truth
  sets (color_spread, roughness_spread; tip_absorption with tip_length);
- "uniform": the default controls, the variation left out of the scenes (`--fix color_spread=0 ...`): the [hair]
  a user who ignored the variation would write.

Each fit's params.json and the command's exit status and wall time are kept under --out/<target>/<kind>/; a fit
already there is not run again (remove it to rerun); --table only tabulates. The Markdown table gives per fit and
control the fitted value ± σ, the truth, the error, |error|/σ and the verdict: within the acceptance bound
(optimize.settings.BOUNDS: albedo 0.02, β 0.03, spreads and tip_absorption 0.05), else within 2σ (the images
cannot pin it to the bound, and σ says so), else a miss; a control without a bound (melanin, tip_length) is
judged by 2σ only. Then per fit χ²/dof (goodness.py) and the exit status (3: the fit says it failed). Wall times
are on whatever else the machine is doing.

--check SPP renders each target's scenes at the truth with warp-hair (SPP samples, seeds 7 and 8) and prints the
channel means against the target's images: whether the two renderers agree on the varied look before any fit,
beside the ratio of the two seeds' means (the noise of such a ratio).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from optimize.latents import DEFAULT_FIT
from optimize.settings import BOUNDS
from optimize.target import SHIPPED_TARGETS, load_target
from warp_hair.cli import exit_on_interrupt
from warp_hair.controls import COLOUR_CONTROLS, CONTROLS, VARIATION_CONTROLS
from warp_hair.geometry.assembly import FiberAssembly
from warp_hair.parallel import default_threads
from warp_hair.renderer.render import render

HERE = Path(__file__).resolve().parent
TARGETS = (
    "cycles_varied_dark",
    "cycles_varied_medium",
    "cycles_varied_light",
    "brown_light_tips",
    "auburn_light_tips_varied",
)
KINDS = ("variation", "uniform")
RECORD = "run.json"  # the command, its exit status and wall time, beside the fit's params.json


def varied(hair) -> list:
    """The variation's controls the look sets away from no variation (a tip's length with its absorption)."""
    names = [name for name in ("color_spread", "roughness_spread") if getattr(hair, name) != 0.0]
    if hair.tip_absorption != 1.0:
        names += ["tip_absorption", "tip_length"]
    return names


def fit_arguments(target, kind: str) -> list:
    """`warp-hair fit`'s --fit (and, for the uniform fit, --fix) for this target."""
    truth = target.truth
    # The default fit's controls, its colour in the look's own colour input (melanin for a melanin look).
    defaults = list(COLOUR_CONTROLS[truth.colour_input]) + [name for name in DEFAULT_FIT if name != "albedo"]
    if kind == "variation":
        return ["--fit", ",".join(defaults + varied(truth))]
    # No variation: the controls at their defaults (a tip's length does nothing without its absorption).
    fixes = [f"{name}={CONTROLS[name].default:g}" for name in varied(truth) if name != "tip_length"]
    return ["--fit", ",".join(defaults), "--fix", *fixes]


def run_fit(directory: Path, kind: str, out: Path, threads) -> dict:
    """`warp-hair fit` of the target as a command; its record (the command, exit status, wall time)."""
    target = load_target(directory)
    command = [sys.executable, "-m", "optimize.cli", "fit", str(directory), "-o", str(out)]
    command += fit_arguments(target, kind) + (["--threads", str(threads)] if threads else [])
    start = time.perf_counter()
    status = subprocess.run(command, check=False).returncode
    record = {
        "command": "warp-hair fit " + " ".join(command[4:]),
        "status": status,
        "wall_seconds": time.perf_counter() - start,
    }
    if status not in (0, 3):  # 3: the fit ran and says it failed; anything else is no fit
        raise RuntimeError(f"{record['command']} exited {status}")
    (out / RECORD).write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    return record


def _fmt(value, digits=3) -> str:
    values = np.atleast_1d(np.asarray(value, dtype=float))
    text = ", ".join(f"{v:.{digits}f}" for v in values)
    return f"({text})" if len(values) > 1 else text


def rows(name: str, kind: str, params: dict, record: dict) -> list:
    """The table's rows of one fit, one per fitted control."""
    lines = []
    goodness = params.get("goodness_of_fit") or {}
    chi2 = goodness.get("chi2_per_dof")
    status = record["status"]
    verdict_fit = f"{status}" + (" (failed)" if params.get("failed") else "")
    fit_cells = ("–" if chi2 is None else f"{chi2:.2f}", verdict_fit, f"{record['wall_seconds']:.0f} s")
    for k, (control, value) in enumerate(params["fitted"].items()):
        if control == "exposure":
            continue
        true = params["true"][control]
        sigma = np.atleast_1d(np.asarray(params["uncertainty"][control], dtype=float))
        error = np.atleast_1d(np.subtract(value, true))
        with np.errstate(divide="ignore"):
            z = np.abs(error) / sigma
        worst = int(np.argmax(np.abs(error)))
        bound = BOUNDS.get(control)
        if np.any(sigma == 0.0):  # the fit found no effect of the control on its renders: σ is not an estimate
            verdict = "**miss**: not moved, σ undetermined"
        elif bound is not None and np.all(np.abs(error) <= bound):
            verdict = "within bound"
        elif np.all(z <= 2.0):
            verdict = "within 2σ" + ("" if bound is not None else " (no bound)")
        else:
            verdict = "**miss**"
        relative = "" if bound is not None else f" ({error[worst] / np.atleast_1d(true)[worst]:+.1%})"
        first = k == 0
        cells = fit_cells if first else ("", "", "")
        lines.append(
            f"| {name if first else ''} | {kind if first else ''} | {control} | {_fmt(value)} ± {_fmt(sigma)} "
            f"| {_fmt(true)} | {error[worst]:+.3f}{relative} | {z[worst]:.1f} | {verdict} | {' | '.join(cells)} |"
        )
    return lines


def table(out: Path, names) -> str:
    lines = [
        "| target | fit | control | fitted ± σ | true | error (worst channel) | \\|error\\|/σ | verdict | χ²/dof "
        "| exit status | wall time |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in names:
        for kind in KINDS:
            folder = out / name / kind
            if (folder / RECORD).is_file() and (folder / "params.json").is_file():
                params = json.loads((folder / "params.json").read_text(encoding="utf-8"))
                record = json.loads((folder / RECORD).read_text(encoding="utf-8"))
                lines += rows(name, kind, params, record)
    return "\n".join(lines)


def reversed_strands(fibers) -> FiberAssembly:
    """The same strands numbered in reverse: each strand draws another's random value."""
    offsets = fibers.strand_offsets
    return FiberAssembly.from_strands(
        (fibers.points[a:b], fibers.radii[a:b]) for a, b in reversed(list(itertools.pairwise(offsets)))
    )


def block_rmse(ours, theirs, block=2) -> float:
    """RMS relative difference of block × block means of the channel sum, over the blocks the fibers light (above
    1% of the brightest): at 2×2, about a strand and a half across, the strand-to-strand pattern counts."""
    h, w = (ours.shape[0] // block) * block, (ours.shape[1] // block) * block

    def blocks(image):
        return image[:h, :w].sum(axis=2).reshape(h // block, block, w // block, block).mean(axis=(1, 3))

    a, b = blocks(ours), blocks(theirs)
    lit = b > 0.01 * b.max()
    return float(np.sqrt(np.mean((a[lit] / b[lit] - 1.0) ** 2)))


def check(directory: Path, spp: int, threads) -> None:
    """warp-hair's render of each scene at the truth against the target's image: channel means and their ratio,
    beside the ratio of two warp-hair seeds' means (what noise alone gives such a ratio); and pixel by pixel
    (`block_rmse`): ours against the image, against another seed of ours (the noise), and two renders that are not
    the target's look, against the image: the strands numbered in reverse (each draws another's random value)
    and the look without its variation."""
    target = load_target(directory)
    for image in target.images:
        scene = image.scene
        ours = render(scene, spp=spp, seed=7, threads=threads)
        again = render(scene, spp=spp, seed=8, threads=threads)
        others = {
            "strands numbered in reverse": dataclasses.replace(scene, fibers=reversed_strands(scene.fibers)),
            "no variation": dataclasses.replace(scene, hair=uniform(scene.hair)),
        }
        theirs = image.image
        a, b = ours.mean(axis=(0, 1)), theirs.mean(axis=(0, 1))
        print(
            f"{directory.name} {image.name}: warp-hair {_fmt(a, 4)}, {target.renderer} {_fmt(b, 4)}, "
            f"ratio {_fmt(a / b, 4)} (two warp-hair seeds: {_fmt(a / again.mean(axis=(0, 1)), 4)}); 2x2-block RMSE "
            f"against {target.renderer} {block_rmse(ours, theirs):.2%} (two seeds {block_rmse(ours, again):.2%}), "
            + ", ".join(
                f"{what} {block_rmse(render(other, spp=spp, seed=7, threads=threads), theirs):.2%}"
                for what, other in others.items()
            ),
            flush=True,
        )


def uniform(hair):
    """The look without its variation: what a user who ignored it would write."""
    return hair.replace(**{name: CONTROLS[name].default for name in VARIATION_CONTROLS})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"shipped target names or directories (default: {', '.join(TARGETS)})")
    parser.add_argument("--out", type=Path, default=HERE / "out" / "variation")
    parser.add_argument("--threads", type=int)
    parser.add_argument("--table", action="store_true", help="only tabulate the fits already under --out")
    parser.add_argument("--check", type=int, metavar="SPP", help="instead: warp-hair at the truth against the images")
    args = parser.parse_args()
    names = args.names or list(TARGETS)
    directories = [Path(n) if Path(n).is_dir() else SHIPPED_TARGETS / n for n in names]
    if args.check:
        for directory in directories:
            check(directory, args.check, args.threads or default_threads())
        return
    for directory in directories:
        for kind in KINDS:
            folder = args.out / directory.name / kind
            if not args.table and not (folder / RECORD).is_file():
                folder.mkdir(parents=True, exist_ok=True)
                record = run_fit(directory, kind, folder, args.threads)
                print(f"{directory.name} {kind}: exit {record['status']}, {record['wall_seconds']:.0f} s", flush=True)
    print(table(args.out, [d.name for d in directories]))


if __name__ == "__main__":
    exit_on_interrupt(main)
