"""Acceptance for photos: fit the photo-like targets (PNG, JPEG, and the same exposures as linear EXR).

    python benchmarks/photo_acceptance.py check      # `targets check` of each: what it says is pinned
    python benchmarks/photo_acceptance.py fit        # `warp-hair fit DIR -o OUT` of each, default settings
    python benchmarks/photo_acceptance.py table      # the Markdown table of docs/acceptance.md from both

The targets are benchmarks/make_photo_targets.py's: the Cycles swatches of light, medium and dark hair, each view
auto-exposed, a white balance off by up to 8%, saved clipped as 8-bit sRGB PNG and JPEG at quality 90 (shipped,
targets/photo_*), and the same exposures unclipped as linear EXR (made here under --out). Each fit starts from the
neutral guess with the photos' gains (one per view) and white balance fitted jointly with albedo, β_m and β_n.

The rule (issue 22): a control `targets check` says the images pin (twice its expected σ within its bound: a fit
then lands within it about 19 times in 20; the σ counts the fit's own renders) must land within its bound
(albedo 0.02 a channel, β 0.03); one it does not say so of must land within 2σ of the fit's own reported σ.
`check` and `fit` write JSON under --out (one file per target) so that they can run apart; each
takes NAMES to run a subset. Times are wall-clock on whatever else the machine is doing.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import make_photo_targets

import targets
from optimize.fit import fit
from optimize.identify import check_target
from optimize.report import write_outputs
from optimize.settings import BOUNDS
from optimize.target import load_target, true_values

HERE = Path(__file__).resolve().parent
KINDS = ("png", "jpeg", "exr")
CONTROLS = ("albedo", "beta_m", "beta_n")


def directories(out: Path) -> dict:
    """{name: target directory} of every photo-like target, the EXR ones made under `out` if missing."""
    found = {}
    for source in make_photo_targets.SOURCES:
        short = source.removeprefix("cycles_")
        for kind in KINDS:
            name = f"photo_{short}_{kind}"
            if kind == "exr":
                directory = out / "targets" / name
                if not (directory / "target.toml").is_file():
                    make_photo_targets.make(source, out / "targets", "exr")
            else:
                directory = targets.path(name)
            found[name] = directory
    return found


def _flat(values: dict) -> list:
    return [float(v) for name in CONTROLS for v in np.atleast_1d(values[name])]


def run_check(name: str, directory: Path, out: Path) -> None:
    target = load_target(directory)
    result = check_target(target)
    record = {
        "labels": result.labels,
        "sigma": result.sigma.tolist(),
        "bounds": result.bounds.tolist(),
        "noise": result.noise.tolist(),
        "fit_noise": None if result.fit_noise is None else result.fit_noise.tolist(),
        "verdicts": result.verdicts,
        "pinned": [verdict == "pinned" for verdict in result.verdicts],
        "camera": result.camera,
    }
    (out / f"{name}.check.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(name, record)


def run_fit(name: str, directory: Path, out: Path) -> None:
    target = load_target(directory)
    result = fit(target)
    write_outputs(out / "fits" / name, result, target)
    truth = true_values(target, result.values)
    record = {
        "values": _flat(result.values),
        "truth": _flat(truth),
        "sigma": _flat(result.uncertainties),
        "camera": result.camera,
        "camera_truth": json.loads((directory / "camera_truth.json").read_text()),
        "seconds": result.seconds,
        "warnings": result.warnings,
        "left_out": [int((~image.mask).sum()) if image.mask is not None else 0 for image in target.images],
    }
    (out / f"{name}.fit.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(name, record)


def table(out: Path, names) -> str:
    rows = [
        "| target | pinned (check) | fitted albedo / β_m / β_n ± σ | error albedo / β_m / β_n | "
        "within bound or 2σ | largest error / σ | gains error | white balance error | left out | time |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in names:
        fit_file, check_file = out / f"{name}.fit.json", out / f"{name}.check.json"
        if not fit_file.is_file():
            continue
        f = json.loads(fit_file.read_text())
        kind = name.rsplit("_", 1)[1]
        # The check of the PNG stands for the JPEG's and the EXR's too (same scenes, same exposures; it does not
        # model JPEG, and the EXR only lacks the PNG's quantisation).
        if not check_file.is_file():
            check_file = out / f"{name.rsplit('_', 1)[0]}_png.check.json"
        c = json.loads(check_file.read_text()) if check_file.is_file() else None
        values, truth, sigma = (np.array(f[k]) for k in ("values", "truth", "sigma"))
        error = values - truth
        bounds = np.array([BOUNDS["albedo"]] * 3 + [BOUNDS["beta_m"], BOUNDS["beta_n"]])
        pinned = np.array(c["pinned"]) if c else np.ones(5, bool)
        ok = np.where(pinned, np.abs(error) <= bounds, np.abs(error) <= 2 * sigma)
        labels = ["a_r", "a_g", "a_b", "β_m", "β_n"]
        pin_text = "all" if pinned.all() else "all but " + ", ".join(l for l, p in zip(labels, pinned) if not p)
        cam, cam_truth = f["camera"], f["camera_truth"]
        gain_err = [100 * (cam["gains"][v][0] / cam_truth["gains"][v] - 1) for v in ("front", "back")]
        wb_err = [100 * (w / t - 1) for w, t in zip(cam["white_balance"]["value"], cam_truth["white_balance"])]
        rows.append(
            f"| {name} ({kind}) | {pin_text if c else 'not checked'} "
            f"| ({values[0]:.3f}, {values[1]:.3f}, {values[2]:.3f}) ± ({sigma[0]:.3f}, {sigma[1]:.3f}, {sigma[2]:.3f})"
            f" / {values[3]:.3f} ± {sigma[3]:.3f} / {values[4]:.3f} ± {sigma[4]:.3f} "
            f"| ({error[0]:+.3f}, {error[1]:+.3f}, {error[2]:+.3f}) / {error[3]:+.3f} / {error[4]:+.3f} "
            f"| {'yes' if ok.all() else 'no: ' + ', '.join(l for l, o in zip(labels, ok) if not o)} "
            f"| {np.max(np.abs(error) / sigma):.1f} "
            f"| {gain_err[0]:+.1f}%, {gain_err[1]:+.1f}% | {wb_err[0]:+.1f}%, {wb_err[2]:+.1f}% "
            f"| {sum(f['left_out'])} | {f['seconds']:.0f} s |"
        )
    if any("| not checked |" in row for row in rows):
        rows.append(
            f"\nnot checked: no `check` result in {out} (run `photo_acceptance.py check --out {out}`); the bounds are "
            "applied to every component of those rows, as if the check had called each pinned"
        )
    return "\n".join(rows)


def check_table(out: Path, names) -> str:
    rows = [
        "| target | σ albedo r, g, b | σ β_m | σ β_n | the fit's renders' part (a_r, a_g, a_b, β_m, β_n) | likely only "
        "| not pinned | gains (front, back) | white balance (r, b) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in names:
        path = out / f"{name}.check.json"
        if not path.is_file():
            continue
        c = json.loads(path.read_text())
        sigma, fitted = c["sigma"], c.get("fit_noise") or [float("nan")] * len(c["sigma"])
        camera = {label: s for label, _, s in c["camera"]}
        verdicts = c.get("verdicts") or ["pinned" if p else "not pinned" for p in c["pinned"]]
        likely = [label for label, v in zip(c["labels"], verdicts) if v == "likely"]
        unpinned = [label for label, v in zip(c["labels"], verdicts) if v == "not pinned"]
        rows.append(
            f"| {name} | {sigma[0]:.4f}, {sigma[1]:.4f}, {sigma[2]:.4f} | {sigma[3]:.4f} | {sigma[4]:.4f} "
            f"| {', '.join(f'{v:.4f}' for v in fitted)} | {', '.join(likely) or 'none'} "
            f"| {', '.join(unpinned) or 'none'} "
            f"| {100 * camera['gain[front]']:.1f}%, {100 * camera['gain[back]']:.1f}% "
            f"| {100 * camera['white_balance[r]']:.2f}%, {100 * camera['white_balance[b]']:.2f}% |"
        )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("action", choices=("check", "fit", "table"))
    parser.add_argument("names", nargs="*", help="photo_<hair>_<png|jpeg|exr> (default all)")
    parser.add_argument("--out", type=Path, default=HERE / "out" / "photo")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    found = directories(args.out)
    names = args.names or list(found)
    unknown = sorted(set(names) - set(found))
    if unknown:
        parser.error(f"unknown target(s) {unknown}; allowed: {sorted(found)}")
    if args.action == "table":
        print(check_table(args.out, names) + "\n\n" + table(args.out, names))
        return
    for name in names:
        if args.action == "check" and not name.endswith("_png"):
            continue  # the PNG's check stands for it (see `table`)
        (run_check if args.action == "check" else run_fit)(name, found[name], args.out)


if __name__ == "__main__":
    main()
