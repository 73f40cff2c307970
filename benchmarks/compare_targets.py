"""Candidate models against a base over several evaluation seeds, from `benchmarks/targets.py --out` files.

One evaluation seed's task returns are noisy (4 episodes per task), and a candidate that wins on one seed can lose
on the next (docs/results.md sections 20-21), so models are judged on several. Each file is one model measured
with one evaluation seed. A model's files follow the base's in the same seed order, and their seeds and settings
must match. For each model the script prints, seed by seed and as the mean: the walk return, the tasks beating
both floors, goal success, tracking EMD, the sum of the task returns, and how many tasks' returns are above the
base's on the same seed.

    python benchmarks/compare_targets.py --base runs/targets-S2-s0.json runs/targets-S2-s1.json \
        --candidate A runs/targets-A-s0.json runs/targets-A-s1.json --candidate B runs/targets-B-s0.json ...
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

FLOORS = ("zero", "random", "settings")
MEASURES = {"walk": "move-ego-0-2", "tasks > floors": "beats_floors", "goal": "goal_success", "EMD": "tracking_emd"}
# (one seed, the mean) per printed column: counts get a decimal in their mean
FORMATS = {"walk": ("{:.1f}", "{:.1f}"), "tasks > floors": ("{:.0f}", "{:.2f}"), "goal": ("{:.3f}", "{:.3f}"),
           "EMD": ("{:.2f}", "{:.2f}"), "sum": ("{:,.0f}", "{:,.0f}"), "> base": ("{:.0f}", "{:.1f}")}


def model_row(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The settings of a targets.py file and the row of its one model (the row that is not a floor)."""
    try:
        data = json.loads(path.read_text())
        names = [k for k in data if k not in FLOORS]
        if len(names) != 1:
            raise SystemExit(f"{path}: expected one model row besides the floors, found {names}")
        row = data[names[0]]
        missing = [k for k in (*MEASURES.values(), "returns") if k not in row]
        if missing:
            raise SystemExit(f"{path}: the row {names[0]!r} has no {', '.join(missing)}")
        return data["settings"], row
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"{path}: not a targets.py --out file ({e})") from None


def compare(base: list[Path], candidate: list[Path]) -> dict[str, list[float]]:
    """Per seed: each measure of `candidate`, its task sum, and its tasks above `base` on the same seed."""
    if len(candidate) != len(base):
        raise SystemExit(f"{len(candidate)} files for a model, {len(base)} for the base: give one per seed")
    out: dict[str, list[float]] = {}
    for b_path, c_path in zip(base, candidate):
        (b_set, b_row), (c_set, c_row) = model_row(b_path), model_row(c_path)
        if b_set != c_set:
            raise SystemExit(f"{c_path}: measured with {c_set}, but {b_path} with {b_set}")
        if c_row["returns"].keys() != b_row["returns"].keys():
            raise SystemExit(f"{c_path}: its tasks differ from those of {b_path}")
        for name, key in MEASURES.items():
            out.setdefault(name, []).append(c_row[key])
        out.setdefault("sum", []).append(sum(c_row["returns"].values()))
        out.setdefault("> base", []).append(sum(r > b_row["returns"][t] for t, r in c_row["returns"].items()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, nargs="+", required=True, help="the base model's files, one per seed")
    ap.add_argument("--candidate", nargs="+", action="append", default=[], metavar="NAME FILE",
                    help="a name, then that model's files in the base's seed order (repeatable)")
    args = ap.parse_args()
    print("seeds " + ", ".join(str(model_row(p)[0].get("seed")) for p in args.base) + "; per seed (mean)")
    for name, *files in [["base", *map(str, args.base)], *args.candidate]:
        if not files:
            ap.error(f"--candidate {name}: give its files after the name")
        res = compare(args.base, [Path(f) for f in files])
        cells = [f"{m} " + " / ".join(FORMATS[m][0].format(v) for v in vals) + f" ({FORMATS[m][1].format(sum(vals) / len(vals))})"
                 for m, vals in res.items() if not (name == "base" and m == "> base")]
        print(f"{name:24s} " + "  ".join(cells))


if __name__ == "__main__":
    main()
