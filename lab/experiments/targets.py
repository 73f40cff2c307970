"""The shipped model's target table (issue: a model that controls the humanoid), next to the floor baselines.

One run evaluates a checkpoint and the zero-action and random-action floors with the same seeds, initial states
and episodes, and prints each measure with its target:
- stand prompt from standing starts: median seconds upright (target: the full episode, 10 s);
- stand prompt from fall starts: share of episodes upright over the last second (target >= 0.5);
- `move-ego-0-2` return of 300 (target >= 100);
- reward tasks on which the model beats both floors (target: 40 of the paper's 45; our registry has more);
- goal success, mean over the named poses (target >= 0.3);
- tracking EMD, mean over the training clips (target <= 3);
- the behaviour families of `fbcpr eval --suite behaviours` (physical checks: get up, jump with flight, sit, hands
  above the head, run, ...; target: 9 of 11 passed), with the same episodes and seed.

    python lab/experiments/targets.py pretrained --motions data/clips/deepmimic --episodes 4 --out runs/targets.json

The floors are seeded and deterministic, so `--floors runs/targets.json` reuses the zero and random rows of an
earlier run with the same settings and costs a third of the time. Beside a training on a 2-core machine, pass
`--threads 1`: unpinned, the benchmark's torch and MuJoCo threads and the training's share the cores and it ran
6x slower (35 min instead of 6).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import torch
from rich.console import Console

from fbcpr.eval.behaviours import check
from fbcpr.eval.behaviours import table as behaviour_table
from fbcpr.eval.report import json_safe
from fbcpr.eval.runner import EPISODE_STEPS, evaluate
from fbcpr.eval.upright import upright
from fbcpr.inference.agents import make_agent


def measure(spec: str, motions: Any, episodes: int, steps: int, seed: int,
            threads: int | None = None) -> dict[str, Any]:
    """Every measure of the table for one agent, plus the per-task returns (to count wins over the floors)."""
    agent = make_agent(spec, seed=seed)
    up = upright(agent, episodes=max(episodes, 8), steps=steps, seed=seed, num_threads=threads)
    res = evaluate(agent, "all", episodes=episodes, motions=motions, steps=steps, seed=seed, show_progress=False,
                   agent_name=spec, num_threads=threads)
    return {"upright_median_s": up.median_seconds, "got_up": up.share_got_up,
            "move-ego-0-2": res["reward"]["move-ego-0-2"]["return_mean"],
            "returns": {t: r["return_mean"] for t, r in res["reward"].items()},
            "goal_success": res["summary"]["goal"]["success"], "tracking_emd": res["summary"]["tracking"]["emd"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agent", help="checkpoint dir, run dir or 'pretrained'")
    ap.add_argument("--motions", default="data/clips/deepmimic", help="folder of the training clips (.npz)")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, help="write all figures as JSON here")
    ap.add_argument("--floors", type=Path, help="take the zero and random rows from this earlier --out file")
    ap.add_argument("--threads", type=int, help="torch and MuJoCo threads (default: all cores); 1 beside a training")
    args = ap.parse_args()
    if args.threads is not None:
        if args.threads < 1:
            ap.error(f"--threads must be >= 1, got {args.threads}")
        torch.set_num_threads(args.threads)
    from motions.library import MotionLibrary

    settings = {"motions": str(args.motions), "episodes": args.episodes, "steps": args.steps, "seed": args.seed}
    rows = {}
    if args.floors:
        earlier = json.loads(args.floors.read_text())
        if earlier.get("settings") != settings:
            raise SystemExit(f"--floors {args.floors}: measured with {earlier.get('settings')}, not {settings}")
        rows = {name: earlier[name] for name in ("zero", "random")}
    motions = MotionLibrary.load(args.motions)
    for name in ("zero", "random", args.agent):
        rows[name] = rows.get(name) or measure(name, motions, args.episodes, args.steps, args.seed, args.threads)
    model, floors = rows[args.agent], [rows["zero"], rows["random"]]
    wins = [t for t, r in model["returns"].items() if all(r > f["returns"][t] for f in floors)]
    for r in rows.values():
        r["beats_floors"] = len(wins) if r is model else math.nan
    table = [("stand prompt, standing start: median upright s", "upright_median_s", ">=", 10.0),
             ("stand prompt, fall start: share upright, last second", "got_up", ">=", 0.5),
             ("move-ego-0-2 return (of 300)", "move-ego-0-2", ">=", 100.0),
             (f"reward tasks beating both floors (of {len(model['returns'])})", "beats_floors", ">=", 40),
             ("goal success, mean over named poses", "goal_success", ">=", 0.3),
             ("tracking EMD, training clips", "tracking_emd", "<=", 3.0)]
    print(f"{'measure':54s} {'zero':>8s} {'random':>8s} {'model':>8s} {'target':>8s} met")
    for label, key, op, target in table:
        value = model[key]
        met = value >= target if op == ">=" else value <= target
        print(f"{label:54s} {rows['zero'][key]:8.2f} {rows['random'][key]:8.2f} {value:8.2f} {op}{target:6g}  "
              f"{'yes' if met else 'no'}")
    print(f"tasks beating both floors: {', '.join(sorted(wins)) or 'none'}")
    behaviours = check({name: make_agent(name, seed=args.seed) for name in (args.agent, "zero", "random")},
                       episodes=max(args.episodes, 8), steps=args.steps, seed=args.seed, show_progress=False,
                       num_threads=args.threads)
    Console().print(behaviour_table(behaviours))
    if args.out:
        args.out.write_text(json.dumps(json_safe({**rows, "settings": settings, "behaviours": behaviours}), indent=1))


if __name__ == "__main__":
    main()
