"""Acceptance of fits that do not know the target's strands (issue 23, section 1): each Cycles swatch fitted with
its scenes holding other realisations of its recipe.

    python benchmarks/realisation_acceptance.py [NAME ...] [--realisations 1 2 3 4 5] [--mode random|fixed]
        [--shift S] [--out benchmarks/out/realisations] [--threads N] [--table] [--own-draw SPP]

For each Cycles target (default: every shipped `cycles_*` target whose fibers come from a generator) and each
realisation k, a copy of the target whose scene files' [fibers] seed (and, for the swatch recipes, shift) are
those of realisation k of the target's own recipe (`warp_hair.realisation.realisation_draw`: another seed, the
strands' lattice moved across the swatch by a uniform fraction of a spacing) is fitted with the default
settings and `realisations = --mode`: "random" (default) fits over random realisations of that recipe
(optimize/realisations.py), "fixed" renders realisation k's strands, as every fit did before (the bias issue
23 measured). The Cycles images are unchanged: they show the target's own strands, which no fit renders.

Each fit's result is kept as JSON under --out/<mode>/<target>/k<k>.json, and a fit already there is not run
again (remove it to rerun); --table only tabulates what is there. The Markdown table gives, per target, the
mean error over its realisations of albedo (per channel, the largest), β_m and β_n with the mean's standard
error, the largest single error, the largest error over the fit's own σ (|error| / σ: whether σ covers it), the
mean σ's realisation part, and whether every fit lies within the acceptance bounds (optimize.identify.BOUNDS).
Wall times are on whatever else the machine is doing.

--target-draws J renders J other realisations of each recipe with the target's renderer (Cycles) as new targets
and fits each over random realisations: the method's bias over the targets' draws, which fits of one target
cannot show (each under --out/target-draws/<target>/, the renders kept).

--own-draw SPP fits nothing: it says where each target's own strands lie among its recipe's realisations
(`own_draw`), which every fit of that target shares, and which half of the draw puts them there: the target's
own seed (its strands' jitter and wander) under the realisations' shifts, and the realisations' seeds under its
own shift.
"""

from __future__ import annotations

import argparse
import copy
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import tomlkit

from optimize.fit import fit
from optimize.settings import ALBEDO_BOUND, BETA_BOUND
from optimize.target import TARGET_FILE, load_target, read_target_spec, shipped_targets, true_values
from warp_hair.cli import exit_on_interrupt
from warp_hair.parallel import default_threads
from warp_hair.realisation import can_realise, realisation_draw
from warp_hair.scene import load_scene

HERE = Path(__file__).resolve().parent
CONTROLS = ("albedo", "beta_m", "beta_n")
# Realisations that --target-draws renders as targets: far from those the fits of the shipped target use (1–5).
TARGET_DRAW_BASE = 100


def other_realisation(source: Path, destination: Path, index: int, mode: str, shift=None) -> None:
    """A copy of target `source` at `destination` whose scenes hold realisation `index` of its recipe (with
    `shift` in place of the drawn one, where given) and whose target.toml says realisations = mode."""
    shutil.copytree(source, destination)
    for entry in read_target_spec(source):
        path = destination / entry["scene"]
        draw = realisation_draw(load_scene(source / entry["scene"]), index)
        if shift is not None:
            draw["shift"] = shift
        document = tomlkit.parse(path.read_text(encoding="utf-8"))
        for key, value in draw.items():
            document["fibers"][key] = value
        path.write_text(tomlkit.dumps(document), encoding="utf-8")
    spec = destination / TARGET_FILE
    document = tomlkit.parse(spec.read_text(encoding="utf-8"))
    document["realisations"] = mode
    spec.write_text(tomlkit.dumps(document), encoding="utf-8")


def target_draw(source: Path, draw: int, out: Path, threads) -> dict:
    """A fit of another *target* realisation: the recipe's realisation TARGET_DRAW_BASE + draw rendered by the
    target's own renderer (Cycles) as a new target (kept under `out`, rendered once), then fitted over random
    realisations of its recipe, which are drawn from its own seed and so never are its strands."""
    from make_peer_targets import make_peer_target

    directory = out / f"target{draw}"
    rendered = directory / "rendered"  # written once the renders are done: a copy holds the source's images before
    if not rendered.is_file():
        shutil.rmtree(directory, ignore_errors=True)
        other_realisation(source, directory, TARGET_DRAW_BASE + draw, "random")
        make_peer_target(directory, threads or default_threads())
        rendered.write_text(f"realisation {TARGET_DRAW_BASE + draw} of {source.name}\n", encoding="utf-8")
    return fit_record(directory, f"{source.name} (target draws)", TARGET_DRAW_BASE + draw, "random", None, threads)


def run_one(source: Path, index: int, mode: str, threads, shift=None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / source.name
        other_realisation(source, copy, index, mode, shift)
        return fit_record(copy, source.name, index, mode, shift, threads)


def fit_record(directory: Path, label: str, index: int, mode: str, shift, threads) -> dict:
    """The default fit of the target at `directory`, as the JSON record the table reads."""
    target = load_target(directory)
    start = time.perf_counter()
    result = fit(target, threads=threads)
    seconds = time.perf_counter() - start
    truth = true_values(target, result.values)
    return {
        "target": label,
        "realisation": index,
        "mode": mode,
        "shift": shift,
        "values": result.values,
        "truth": {name: truth[name] for name in result.values},
        "uncertainties": result.uncertainties,
        "parts": result.uncertainty_parts,
        "seconds": seconds,
        "stop_reason": result.stop_reason,
    }


def own_draw(source: Path, spp: int, samples: int, threads=None, pool: int | None = None) -> dict:
    """How far the target's own strands lie from the realisation average, for β_n and the rest: with warp-hair
    alone at the true controls, where a fit over random realisations would land were the target warp-hair's
    render of realisation k, u_k = H⁻¹ Aᵀ W (I_k − Ī) (k = 0 the scene's own strands, 1…samples others; A and H
    from a random-realisation linearisation with the others' Jacobians pooled in, as the fit's realisation term
    takes them; Ī the mean over 1…samples). Each u_k is taken per pass; the
    spread is the fit's own realisation term over 1…samples (`realisation_term`), free of our render noise.
    Every fit of one target shares its u_0: a mean over fits of one target does not average it out."""
    from optimize.fit import FitSettings
    from optimize.linearize import linearize
    from optimize.realisations import Realisations, estimate_gain, pooled_jacobians, realisation_term
    from warp_hair.renderer.prepare import prepare

    target = load_target(source)
    names = list(CONTROLS)
    truth = true_values(target, names)
    realisations = Realisations(target)
    settings = FitSettings() if pool is None else FitSettings(pool=pool)
    lin = linearize(target, truth, settings, spp, 1, threads=threads, scenes=realisations.pair(1))
    own = [prepare(image.scene) for image in target.images]
    lins = [
        linearize(
            target, truth, settings, spp, 100 + k, threads=threads, scenes=own if k == 0 else realisations.scenes(k)
        )
        for k in range(samples + 1)
    ]
    # The gain the fit's realisation term uses: its Jacobians pooled with the realisations' (realisations.py).
    gain = estimate_gain(pooled_jacobians(lin, lins[1:]))
    residuals = np.stack([one.residuals for one in lins])  # (samples + 1, 2, N)
    mean = residuals[1:].mean(axis=0)
    u = np.einsum("pn,khn->khp", gain, residuals - mean)
    spread = realisation_term(lin, lins[1:]).covariance

    def moved(scenes, seed):  # u of other strands, per pass averaged
        r = linearize(target, truth, settings, spp, seed, threads=threads, scenes=scenes).residuals
        return np.einsum("pn,hn->hp", gain, r - mean).mean(axis=0)

    shifts = "shift" in realisation_draw(target.images[0].scene, 1)  # a swatch recipe: its lattice moves
    return {
        "own": u[0].mean(axis=0),
        "own_per_pass": u[0],
        "others": u[1:].mean(axis=1),
        "spread": np.sqrt(np.diag(spread)),
        # The two halves of a draw: the target's own seed (its strands' jitter and wander) with the shifts of
        # realisations 1…samples, and the seeds of those realisations at the target's own shift.
        "own_seed": np.array(
            [moved(_redrawn(target, k, seed=False), 200 + k) for k in range(1, samples + 1)] if shifts else []
        ),
        "own_shift": np.array(
            [moved(_redrawn(target, k, shift=False), 300 + k) for k in range(1, samples + 1)] if shifts else []
        ),
    }


def _redrawn(target, index: int, seed: bool = True, shift: bool = True) -> list:
    """The target's prepared scenes with realisation `index`'s seed and/or shift only (the rest the scene's own)."""
    from warp_hair.renderer.prepare import prepare
    from warp_hair.scene import scene_from_dict

    scenes = []
    for image in target.images:
        source = copy.deepcopy(image.scene.source)
        draw = realisation_draw(image.scene, index)
        source["fibers"].update(
            {key: value for key, value in draw.items() if (key != "seed" or seed) and (key != "shift" or shift)}
        )
        scenes.append(prepare(scene_from_dict(source, where=f"{image.scene.path} (realisation {index}, in part)")))
    return scenes


def _errors(record: dict) -> dict:
    return {
        name: np.atleast_1d(np.subtract(record["values"][name], record["truth"][name])).astype(float)
        for name in CONTROLS
    }


def table(records: list) -> str:
    lines = [
        "| target | fits | albedo mean error (± s.e.), worst channel | β_m mean error | β_n mean error "
        "| largest single error (albedo, β_m, β_n) | max \\|error\\|/σ | σ realisation part (albedo, β_m, β_n) "
        "| all within bounds | mean wall time |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in sorted({r["target"] for r in records}):
        runs = [r for r in records if r["target"] == name]
        errors = [_errors(r) for r in runs]
        n = len(runs)
        cells = []
        for control in CONTROLS:
            stacked = np.stack([e[control] for e in errors])  # (n, channels)
            mean = stacked.mean(axis=0)
            se = stacked.std(axis=0, ddof=1) / np.sqrt(n) if n > 1 else np.full_like(mean, np.nan)
            worst = int(np.argmax(np.abs(mean)))
            cells.append(f"{mean[worst]:+.3f} ± {se[worst]:.3f}")
        largest = [max(float(np.max(np.abs(e[c]))) for e in errors) for c in CONTROLS]
        z = max(
            float(np.max(np.abs(e[c]) / np.asarray(np.atleast_1d(r["uncertainties"][c]), float)))
            for e, r in zip(errors, runs)
            if r["uncertainties"]
            for c in CONTROLS
        )
        realised = []
        for c in CONTROLS:
            parts = [r["parts"]["realisation"][c] for r in runs if r["parts"] and r["parts"].get("realisation")]
            worst = np.asarray(parts, float).reshape(len(parts), -1).max(axis=1) if parts else None
            realised.append(f"{float(np.mean(worst)):.3f}" if parts else "–")
        ok = all(
            float(np.max(np.abs(e["albedo"]))) <= ALBEDO_BOUND
            and float(np.abs(e["beta_m"][0])) <= BETA_BOUND
            and float(np.abs(e["beta_n"][0])) <= BETA_BOUND
            for e in errors
        )
        seconds = np.mean([r["seconds"] for r in runs])
        lines.append(
            f"| {name} ({runs[0]['mode']}{'' if runs[0].get('shift') is None else ', shift ' + str(runs[0]['shift'])}) "
            f"| {n} | {cells[0]} | {cells[1]} | {cells[2]} | "
            f"{largest[0]:.3f}, {largest[1]:.3f}, {largest[2]:.3f} | {z:.1f} | {', '.join(realised)} | "
            f"{'yes' if ok else 'no'} | {seconds:.0f} s |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="shipped target names or directories (default: every cycles_*)")
    parser.add_argument("--realisations", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--mode", choices=("random", "fixed"), default="random")
    parser.add_argument("--out", type=Path, default=HERE / "out" / "realisations")
    parser.add_argument("--threads", type=int)
    parser.add_argument(
        "--shift",
        type=float,
        help="move the strands by this fraction of a spacing instead of the drawn one (issue 23's experiment: 0.5, "
        "the fit's strands where the target's gaps are); results go under --out/<mode>-shift<S>",
    )
    parser.add_argument("--table", action="store_true", help="only tabulate the fits already under --out")
    parser.add_argument(
        "--own-draw",
        type=int,
        metavar="SPP",
        help="instead of fitting: where the target's own strands lie among realisations 1..8 (`own_draw`), at SPP",
    )
    parser.add_argument("--pool", type=int, help="with --own-draw: the loss's k×k blocks (default the fit's)")
    parser.add_argument(
        "--target-draws",
        type=int,
        metavar="J",
        help="instead: J other realisations rendered by the target's renderer as targets, each fitted over random "
        "realisations (`target_draw`; the method's bias over target draws, not one draw's); under --out/target-draws",
    )
    args = parser.parse_args()
    given = [Path(n) for n in args.names if Path(n).is_dir()]
    directories = given + [
        d
        for d in shipped_targets()
        if (d.name in args.names or (not args.names and d.name.startswith("cycles_")))
        and can_realise(load_scene(d / read_target_spec(d)[0]["scene"]))
    ]
    if args.own_draw:
        labels = "albedo r, g, b, β_m, β_n"
        for directory in directories:
            draw = own_draw(directory, args.own_draw, 8, args.threads, args.pool)
            print(f"{directory.name} ({labels}): own strands {np.round(draw['own'], 4)} (passes "
                  f"{np.round(draw['own_per_pass'], 4).tolist()}); realisation spread {np.round(draw['spread'], 4)}; "
                  f"others {np.round(draw['others'][:, -1], 4).tolist()} in β_n")  # fmt: skip
            for key, what in (
                ("own_seed", "its own seed, realisations' shifts"),
                ("own_shift", "its own shift, realisations' seeds"),
            ):
                if len(draw[key]):
                    values = draw[key][:, -1]
                    print(f"  {what}: β_n {np.round(values, 4).tolist()}, mean {values.mean():+.4f} ± "
                          f"{values.std(ddof=1) / np.sqrt(len(values)):.4f}")  # fmt: skip
        return
    if args.target_draws:
        records = []
        for directory in directories:
            for draw in range(1, args.target_draws + 1):
                folder = args.out / "target-draws" / directory.name
                path = folder / f"j{draw}.json"
                if not path.exists() and not args.table:
                    record = target_draw(directory, draw, folder, args.threads)
                    path.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
                    print(
                        f"{directory.name} target draw {draw}: "
                        + ", ".join(f"{c} {_errors(record)[c]}" for c in CONTROLS)
                    )
                if path.exists():
                    records.append(json.loads(path.read_text(encoding="utf-8")))
        print(table(records))
        return
    records = []
    for directory in directories:
        for index in args.realisations:
            folder = args.mode if args.shift is None else f"{args.mode}-shift{args.shift:g}"
            path = args.out / folder / directory.name / f"k{index}.json"
            if not path.exists() and not args.table:
                record = run_one(directory, index, args.mode, args.threads, args.shift)
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
                print(f"{directory.name} k={index}: " + ", ".join(f"{c} {_errors(record)[c]}" for c in CONTROLS))
            if path.exists():
                records.append(json.loads(path.read_text(encoding="utf-8")))
    print(table(records))


if __name__ == "__main__":
    exit_on_interrupt(main)
