"""Whether fits keep their σ: |error|/σ over every fitted control component of many fits, and the fits that said
they failed.

    python benchmarks/error_over_sigma.py DIR [DIR ...]

Reads every params.json below the directories (what `warp-hair fit -o`, benchmarks/fit_targets.py and
benchmarks/photo_acceptance.py write) and every k*.json of benchmarks/realisation_acceptance.py, keeps those with
a truth, and prints per fit its largest |error|/σ and whether it failed, then the promise's tally: the share of
components within 2σ (the rule: about 19 in 20) and within 3σ (all), over the fits that did not say they failed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _flat(values: dict, names) -> np.ndarray:
    return np.concatenate([np.atleast_1d(np.asarray(values[name], dtype=np.float64)) for name in names])


def records(roots) -> list:
    """(name, |error|/σ per component, failed) of every fit with a truth below `roots`."""
    out = []
    for root in roots:
        for path in sorted(Path(root).rglob("*.json")):
            if path.name != "params.json" and not path.name.startswith("k"):
                continue
            data = json.loads(path.read_text(encoding="utf-8"))
            # params.json's keys, else realisation_acceptance.py's
            truth = data.get("true") or data.get("truth")
            sigma = data.get("uncertainty") or data.get("uncertainties")
            fitted = data.get("fitted") or data.get("values")
            if not truth or not sigma or not fitted:
                continue
            names = [name for name in fitted if name in truth and name in sigma]
            error = _flat(fitted, names) - _flat(truth, names)
            ratio = np.abs(error) / np.maximum(_flat(sigma, names), 1e-300)
            out.append(
                (
                    str(path.parent.relative_to(root)) + ("" if path.name == "params.json" else f"/{path.stem}"),
                    ratio,
                    bool(data.get("failed", False)),
                )
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("roots", nargs="+", type=Path)
    args = parser.parse_args()
    rows = records(args.roots)
    if not rows:
        raise SystemExit("no fit with a truth found under " + ", ".join(map(str, args.roots)))
    print("| fit | largest \\|error\\|/σ | failed |\n| --- | --- | --- |")
    for name, ratio, failed in rows:
        print(f"| {name} | {ratio.max():.2f} | {'yes' if failed else ''} |")
    kept = np.concatenate([ratio for _, ratio, failed in rows if not failed] or [np.zeros(0)])
    failed = sum(failed for *_, failed in rows)
    print(
        f"\n{len(rows)} fits, {failed} said they failed; over the other {len(rows) - failed} fits' {kept.size} "
        f"components: {np.mean(kept <= 2):.1%} within 2σ, {np.mean(kept <= 3):.1%} within 3σ, largest "
        f"{kept.max() if kept.size else float('nan'):.2f}σ"
    )


if __name__ == "__main__":
    main()
