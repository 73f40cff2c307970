"""FB-CPR's policy regulariser on the point mass: the discriminator (the paper) vs the z-conditioned NEAR energy
(`agent.regulariser: near`, fbcpr/rewards/near/conditional.py), at the same budget and seeds, zero-shot metrics as in
lab/log.md section 1 (goal success and proximity, reward returns, imitation error).

    python lab/experiments/toy_regulariser.py [--steps 30000] [--seeds 0 1 2] [--out runs/toy-reg]

Both runs use fbcpr/configs/toy.yaml unchanged (same networks, rates, nu mixture, update ratio, buffer); the NEAR runs
switch `agent.regulariser` to near with the toy sizes of its `agent.near:` section below (NEAR_TOY: those of
fbcpr/configs/near-toy.yaml where they apply). Runs go one at a time; results.json is rewritten after each, and a later call with
more --seeds adds to it.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from toy_learning import run_seed  # the sibling script (lab/experiments/ is on sys.path when run)
from fbcpr.core.config import find_config, load_config
from fbcpr.eval.toy import evaluate

#: The NEAR section for the toy: sigma_1 = 1 (the features are standardised, so the paper's sigma_1 = 20 noise would
#: drown the data), the energy size, rate and EMA of fbcpr/configs/near-toy.yaml; the paper's ladder length, annealing and
#: tanh transform otherwise.
NEAR_TOY = {"sigma_max": 1.0, "hidden_dim": 128, "hidden_layers": 3, "lr": 1e-3, "ema": 0.99}
METRICS = ("goal_success", "goal_proximity", "goal_final_dist", "return/reach-top-right", "return/left-wall",
           "return/ring", "return/bottom-strip", "track_error", "track_within_0.1")


def config(regulariser: str, seed: int, steps: int, eval_every: int):
    cfg = load_config(find_config("toy"))
    cfg.agent.regulariser = regulariser
    for k, v in NEAR_TOY.items():
        setattr(cfg.agent.near, k, v)
    cfg.train.seed, cfg.train.total_env_steps, cfg.train.eval_every = seed, steps, eval_every
    return cfg


def table(results: dict) -> str:
    """Markdown rows: mean +- std over seeds of the last evaluation, per regulariser, with the wall-clock."""
    lines = ["| metric | random | " + " | ".join(results["runs"]) + " |", "|---|---|" + "---|" * len(results["runs"])]
    for k in METRICS + ("train_seconds",):
        cells = []
        for runs in results["runs"].values():
            vals = np.array([r["train_seconds"] if k == "train_seconds" else r["trained"][-1][k] for r in runs])
            cells.append(f"{vals.mean():.2f} ± {vals.std():.2f} (n={len(vals)})")
        rnd = f"{results['random'][k]:.2f}" if k in results["random"] else ""
        lines.append(f"| {k} | {rnd} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=30_000)
    ap.add_argument("--eval-every", type=int, default=10_000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--regularisers", nargs="+", default=["near", "discriminator"])
    ap.add_argument("--out", default="runs/toy-reg")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "results.json"
    results = {"random": evaluate(None, seed=123), "runs": {r: [] for r in args.regularisers},
               "near_toy": NEAR_TOY, "steps": args.steps}
    if saved.is_file():  # more seeds into the same table: runs already there (same budget) are kept, not redone
        results = json.loads(saved.read_text())
        if results["steps"] != args.steps or results["near_toy"] != NEAR_TOY:
            raise SystemExit(f"{saved}: measured with another budget or NEAR section; pick another --out")
    for seed in args.seeds:  # seed-major: an interrupted benchmark still holds both regularisers
        for reg in args.regularisers:
            if any(r["seed"] == seed for r in results["runs"].setdefault(reg, [])):
                continue
            cfg = config(reg, seed, args.steps, args.eval_every)
            results["runs"][reg].append(run_seed(seed, None, out / f"{reg}-seed{seed}", cfg))
            (out / "results.json").write_text(json.dumps(results, indent=1))
            print(table(results), flush=True)


if __name__ == "__main__":
    main()
