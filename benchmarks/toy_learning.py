"""Learning evidence on the point mass: FB-CPR vs its untrained self vs a random policy, zero-shot.

    python benchmarks/toy_learning.py [--steps 40000] [--out runs/toy-bench]

Trains with configs/toy.yaml, evaluates goal reaching, reward maximisation and demo imitation
(fbcpr.toy.evaluate) every eval_every env steps, writes results.json and docs/img/toy_learning.png.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from fbcpr.config import load_config
from fbcpr.toy.evaluate import evaluate
from fbcpr.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--out", default=str(ROOT / "runs" / "toy-bench"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plot", default=str(ROOT / "docs" / "img" / "toy_learning.png"))
    args = ap.parse_args()
    cfg = load_config(ROOT / "configs" / "toy.yaml")
    cfg.train.seed = args.seed
    if args.steps:
        cfg.train.total_env_steps = args.steps
    torch.set_num_threads(cfg.train.torch_threads or 1)
    trainer = Trainer(cfg, args.out, progress=False)
    history = {"random": evaluate(None, seed=123), "steps": [0], "trained": [evaluate(trainer.agent.model, seed=123)]}
    print("random   ", json.dumps({k: round(v, 3) for k, v in history["random"].items() if "/" not in k or "return" in k}))
    print("untrained", json.dumps({k: round(v, 3) for k, v in history["trained"][0].items() if "/" not in k or "return" in k}))
    t0 = time.perf_counter()
    every = cfg.train.eval_every
    while trainer.env_steps < cfg.train.total_env_steps:
        if trainer.run(max_env_steps=every)["interrupted"]:
            break
        res = evaluate(trainer.agent.model, seed=123)
        history["steps"].append(trainer.env_steps)
        history["trained"].append(res)
        print(f"{trainer.env_steps:6d} steps {time.perf_counter() - t0:6.0f}s",
              json.dumps({k: round(v, 3) for k, v in res.items() if "/" not in k or "return" in k}), flush=True)
    history["train_seconds"] = time.perf_counter() - t0
    history["updates"] = trainer.updates
    Path(args.out, "results.json").write_text(json.dumps(history, indent=1))
    plot(history, Path(args.plot))


def plot(h: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ["goal_final_dist", "goal_proximity", "return/reach-top-right", "return/left-wall", "return/ring",
            "return/bottom-strip", "track_error", "track_within_0.1"]
    fig, axes = plt.subplots(2, 4, figsize=(16, 7))
    for ax, k in zip(axes.flat, keys):
        ax.plot(h["steps"], [r[k] for r in h["trained"]], "o-", label="FB-CPR (step 0 = untrained)")
        ax.axhline(h["random"][k], color="gray", ls="--", label="random policy")
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
