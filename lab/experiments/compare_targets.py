"""Candidate models against a base over several evaluation seeds, from `lab/experiments/targets.py --out` files.

One evaluation seed's task returns are noisy (4 episodes per task), and a candidate that wins on one seed can lose
on the next (lab/log.md sections 20-21), so models are judged on several. Each file is one model measured
with one evaluation seed. A model's files follow the base's in the same seed order, and their seeds and settings
must match. For each model the script prints, seed by seed and as the mean: the walk return, the tasks beating
both floors, goal success, tracking EMD, the sum of the task returns, and how many tasks' returns are above the
base's on the same seed.

With `--pushes`, the pushed starts each model held (`lab/experiments/upright_time.py --push 0.1 0.3` over seeds 1-8,
of 128: the count, or that script's `--out` files, one per seed), it also applies the shipping rule fixed in
lab/log.md sections 21-22 and names the clauses a candidate fails: it replaces the base only if its mean
walk and mean task sum are above the base's, its mean count of tasks beating both floors is at least the base's
less 0.5, its mean goal success at least the base's, its mean EMD at most the base's plus 0.1, and it holds at
least the base's pushes less 6.

With `--noise`, the files of noise copies of the base (`lab/experiments/noise_copy.py`: the same policy, to 1e-4 in its
actions, whose rollouts the chaotic physics still sends elsewhere), it prints each copy's row and, per measure, the
largest distance of a copy's mean from the base's mean: the noise floor. The rule then widens every margin by it:
a candidate's mean walk and task sum must beat the base's by more than the floor, and its tasks, goal success and
EMD may fall short of the base by the floor too. A copy of the base fails the rule of sections 21-22 (section 27).
`--floors` gives floors measured before instead (section 27's, which the rule of sections 41-44 uses: `--floors
walk=4.7 tasks=0.17 goal=0.005 EMD=0.11 sum=16`); with copies as well, each measure takes the larger.

`--rule no-loss` applies section 45's rule in place of that of sections 21-44: the walk and the task sum need only
not fall below the base's by more than the floor, the other clauses stay, and the candidate must gain beyond the
floor on at least two of walk, goal success, EMD (lower) and task sum (the clause "two gains").

    python lab/experiments/compare_targets.py --base runs/targets-S2-s0.json runs/targets-S2-s1.json \
        --candidate A runs/targets-A-s0.json runs/targets-A-s1.json --candidate B runs/targets-B-s0.json ... \
        --pushes base 95 --pushes A 101 --pushes B runs/up-B-s1.json runs/up-B-s2.json ... \
        --noise runs/targets-S2p-s0.json runs/targets-S2p-s1.json --noise runs/targets-S2q-s0.json ...
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

#: the keys of a targets.py file that are not the model row: the floors, the settings, the behaviour table
NOT_MODEL = ("zero", "random", "settings", "behaviours")
MEASURES = {"walk": "move-ego-0-2", "tasks > floors": "beats_floors", "goal": "goal_success", "EMD": "tracking_emd"}
# (one seed, the mean) per printed column: counts get a decimal in their mean
FORMATS = {"walk": ("{:.1f}", "{:.1f}"), "tasks > floors": ("{:.0f}", "{:.2f}"), "goal": ("{:.3f}", "{:.3f}"),
           "EMD": ("{:.2f}", "{:.2f}"), "sum": ("{:,.0f}", "{:,.0f}"), "> base": ("{:.0f}", "{:.1f}")}


def only_model(path: Path, data: dict[str, Any]) -> str:
    """The name of the one model row of a results file (the row that is not a floor or the settings)."""
    names = [k for k in data if k not in NOT_MODEL]
    if len(names) != 1:
        raise SystemExit(f"{path}: expected one model row besides the floors, found {names}")
    return names[0]


def model_row(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The settings of a targets.py file and the row of its one model (the row that is not a floor)."""
    try:
        data = json.loads(path.read_text())
        name = only_model(path, data)
        row = data[name]
        missing = [k for k in (*MEASURES.values(), "returns") if k not in row]
        if missing:
            raise SystemExit(f"{path}: the row {name!r} has no {', '.join(missing)}")
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


def pushes_held(files: list[Path]) -> int:
    """Pushed starts held by the one model of `lab/experiments/upright_time.py --out` files, summed over their seeds,
    which must differ, with the same push and episodes in all of them."""
    held, first, seeds = 0, None, set()
    for path in files:
        try:
            data = json.loads(path.read_text())
            held += int(data[only_model(path, data)]["pushed_held"])
            seed, rest = data["settings"]["seed"], {k: v for k, v in data["settings"].items() if k != "seed"}
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
            raise SystemExit(f"{path}: not an upright_time.py --out file measured with --push ({e})") from None
        first = rest if first is None else first
        if rest != first:
            raise SystemExit(f"{path}: measured with {rest}, the first file with {first}")
        if seed in seeds:
            raise SystemExit(f"{path}: seed {seed} is in another file too")
        seeds.add(seed)
    return held


def noise_floor(base: dict[str, list[float]], copies: list[dict[str, list[float]]]) -> dict[str, float]:
    """Per measure, the largest distance between a noise copy's mean and the base's mean (0 without copies)."""
    return {m: max((abs(_mean(c[m]) - _mean(base[m])) for c in copies), default=0.0) for m in base}


#: `--floors` keys and the measures they set
FLOOR_KEYS = {"walk": "walk", "tasks": "tasks > floors", "goal": "goal", "EMD": "EMD", "sum": "sum"}


def parse_floors(items: list[str]) -> dict[str, float]:
    """`KEY=VALUE` items (keys of FLOOR_KEYS, values finite and at least 0) as a noise floor per measure."""
    floors = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in FLOOR_KEYS:
            raise ValueError(f"{item!r}: the key must be one of {', '.join(FLOOR_KEYS)}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"{item!r}: the value must be a number") from None
        if not 0 <= number < float("inf"):
            raise ValueError(f"{item!r}: the value must be finite and at least 0")
        floors[FLOOR_KEYS[key]] = number
    return floors


def _mean(values: list[float]) -> float:
    return sum(values) / len(values)


#: `--rule` names: "gain" is the rule of sections 21-44, "no-loss" the rule of section 45 (module docstring)
RULES = ("gain", "no-loss")


def rule_failures(base: dict[str, list[float]], candidate: dict[str, list[float]], base_pushes: int,
                  candidate_pushes: int, noise: dict[str, float] | None = None, rule: str = "gain") -> list[str]:
    """The clauses of the shipping `rule` (module docstring) that a candidate fails against the base, each margin
    widened by the `noise` floor of that measure; [] ships."""
    if rule not in RULES:
        raise ValueError(f"rule {rule!r}: must be one of {', '.join(RULES)}")
    b, c = ({m: _mean(res[m]) for m in base} for res in (base, candidate))
    n = {m: 0.0 for m in base} | (noise or {})
    gains = {"walk": c["walk"] > b["walk"] + n["walk"], "goal": c["goal"] > b["goal"] + n["goal"],
             "EMD": c["EMD"] < b["EMD"] - n["EMD"], "sum": c["sum"] > b["sum"] + n["sum"]}
    if rule == "gain":
        checks = {"walk": gains["walk"], "sum": gains["sum"]}
    else:
        checks = {"walk": c["walk"] >= b["walk"] - n["walk"], "sum": c["sum"] >= b["sum"] - n["sum"]}
    checks |= {"tasks": c["tasks > floors"] >= b["tasks > floors"] - 0.5 - n["tasks > floors"],
               "goal": c["goal"] >= b["goal"] - n["goal"], "EMD": c["EMD"] <= b["EMD"] + 0.1 + n["EMD"],
               "pushes": candidate_pushes >= base_pushes - 6}
    if rule == "no-loss":
        checks["two gains"] = sum(gains.values()) >= 2
    return [clause for clause, ok in checks.items() if not ok]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, nargs="+", required=True, help="the base model's files, one per seed")
    ap.add_argument("--candidate", nargs="+", action="append", default=[], metavar="NAME FILE",
                    help="a name, then that model's files in the base's seed order (repeatable)")
    ap.add_argument("--pushes", nargs="+", action="append", default=[], metavar="NAME HELD",
                    help="pushed starts a model held, of 128, as a count or upright_time.py --out files (NAME base "
                         "for the base; repeatable): applies the rule")
    ap.add_argument("--noise", type=Path, nargs="+", action="append", default=[], metavar="FILE",
                    help="a noise copy of the base: its files in the base's seed order (repeatable); sizes the "
                         "noise floor that the rule's margins add")
    ap.add_argument("--rule", choices=RULES, default="gain",
                    help="gain: walk and sum above the base's (sections 21-44); no-loss: no measure below the "
                         "base's, and gains on two of walk, goal, EMD and sum (section 45)")
    ap.add_argument("--floors", nargs="+", default=[], metavar="KEY=VALUE",
                    help="noise floors measured before, keys " + ", ".join(FLOOR_KEYS) + " (section 27: walk=4.7 "
                         "tasks=0.17 goal=0.005 EMD=0.11 sum=16); with --noise, each measure takes the larger")
    args = ap.parse_args()
    try:
        given = parse_floors(args.floors)
    except ValueError as e:
        ap.error(f"--floors {e}")
    pushes = {}
    for name, *held in args.pushes:
        if len(held) == 1 and held[0].isdigit():
            pushes[name] = int(held[0])
        elif held and not any(h.isdigit() for h in held):
            pushes[name] = pushes_held([Path(h) for h in held])
        else:
            ap.error(f"--pushes {name}: give one count of held starts, or upright_time.py --out files, got {held}")
    names = {"base", *(c[0] for c in args.candidate)}
    if set(pushes) - names:
        ap.error(f"--pushes: no model named {sorted(set(pushes) - names)[0]!r}")
    if pushes and "base" not in pushes:
        ap.error("--pushes: give the base's count too (--pushes base N)")
    base_res = compare(args.base, args.base)
    noise = noise_floor(base_res, [compare(args.base, files) for files in args.noise])
    noise = {m: max(v, given.get(m, 0.0)) for m, v in noise.items()}
    print("seeds " + ", ".join(str(model_row(p)[0].get("seed")) for p in args.base) + "; per seed (mean)")
    copies = [[f"noise copy {i + 1}", *map(str, files)] for i, files in enumerate(args.noise)]
    for name, *files in [["base", *map(str, args.base)], *copies, *args.candidate]:
        if not files:
            ap.error(f"--candidate {name}: give its files after the name")
        res = compare(args.base, [Path(f) for f in files])
        cells = [f"{m} " + " / ".join(FORMATS[m][0].format(v) for v in vals) + f" ({FORMATS[m][1].format(sum(vals) / len(vals))})"
                 for m, vals in res.items() if not (name == "base" and m == "> base")]
        if name != "base" and name in pushes:
            failed = rule_failures(base_res, res, pushes["base"], pushes[name], noise, args.rule)
            cells.append(f"pushes {pushes[name]}/128  rule: " + ("passes" if not failed else "fails " + ", ".join(failed)))
        print(f"{name:24s} " + "  ".join(cells))
    if args.noise or given:
        print(f"{'noise floor':24s} " + "  ".join(f"{m} ±" + FORMATS[m][1].format(v) for m, v in noise.items()
                                                  if m != "> base"))


if __name__ == "__main__":
    main()
