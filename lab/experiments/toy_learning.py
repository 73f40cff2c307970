"""Learning evidence on the point mass: FB-CPR vs its untrained self vs a random policy, zero-shot.

    python lab/experiments/toy_learning.py [--steps 60000] [--seeds 0 1 2 3] [--out runs/toy-bench]

Trains with fbcpr/configs/toy.yaml, evaluates goal reaching, reward maximisation and demo imitation
(fbcpr.eval.toy) every eval_every env steps, writes results.json and docs/img/toy_learning.png.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from fbcpr.core.config import find_config, load_config
from fbcpr.core.schema import Config
from fbcpr.eval.toy import evaluate
from fbcpr.train.trainer import Trainer

ROOT = Path(__file__).resolve().parents[2]  # the repository root: figures go to its docs/img/


def run_seed(seed: int, steps: int | None, out: Path, cfg: Config | None = None) -> dict:
    """Train `cfg` (default fbcpr/configs/toy.yaml) with one seed, evaluating every eval_every env steps; the history of
    one run."""
    cfg = cfg or load_config(find_config("toy"))
    cfg.train.seed = seed
    if steps:
        cfg.train.total_env_steps = steps
    torch.set_num_threads(cfg.train.torch_threads or 1)
    trainer = Trainer(cfg, out, progress=False)
    history = {"seed": seed, "steps": [0], "trained": [evaluate(trainer.agent.model, seed=123)]}
    t0 = time.perf_counter()
    while trainer.env_steps < cfg.train.total_env_steps:
        if trainer.run(max_env_steps=cfg.train.eval_every)["interrupted"]:
            break
        res = evaluate(trainer.agent.model, seed=123)
        history["steps"].append(trainer.env_steps)
        history["trained"].append(res)
        print(f"seed {seed} {trainer.env_steps:6d} steps {time.perf_counter() - t0:6.0f}s",
              json.dumps({k: round(v, 3) for k, v in res.items() if "/" not in k or "return" in k}), flush=True)
    history["train_seconds"] = time.perf_counter() - t0
    history["updates"] = trainer.learner.updates
    return history


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--out", default="runs/toy-bench")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--plot", default=str(ROOT / "docs" / "img" / "toy_learning.png"))
    args = ap.parse_args()
    results = {"random": evaluate(None, seed=123)}
    print("random", json.dumps({k: round(v, 3) for k, v in results["random"].items() if "/" not in k or "return" in k}))
    results["runs"] = [run_seed(seed, args.steps, Path(args.out) / f"seed{seed}") for seed in args.seeds]
    Path(args.out, "results.json").write_text(json.dumps(results, indent=1))
    plot(results, Path(args.plot))


def plot(results: dict, path: Path) -> None:
    """One panel per metric: each seed's curve (thin), their mean (thick), the random policy (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ["goal_final_dist", "goal_proximity", "return/reach-top-right", "return/left-wall", "return/ring",
            "return/bottom-strip", "track_error", "track_within_0.1"]
    fig, axes = plt.subplots(2, 4, figsize=(16, 7))
    runs = results["runs"]
    n = min(len(r["steps"]) for r in runs)
    for ax, k in zip(axes.flat, keys):
        curves = np.array([[t[k] for t in r["trained"][:n]] for r in runs])
        for r, c in zip(runs, curves):
            ax.plot(r["steps"][:n], c, "-", color="tab:blue", alpha=0.3, lw=1)
        ax.plot(runs[0]["steps"][:n], curves.mean(0), "o-", color="tab:blue",
                label=f"FB-CPR, mean of {len(runs)} seeds (step 0 = untrained)")
        ax.axhline(results["random"][k], color="gray", ls="--", label="random policy")
        ax.set_title(k)
        ax.set_xlabel("env steps")
    axes.flat[0].legend()
    fig.suptitle("2-D point toy: zero-shot goal reaching, reward maximisation and demo imitation")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    print("plot:", path)


if __name__ == "__main__":
    main()
