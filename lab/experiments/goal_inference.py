"""Goal success under each goal inference (`Prompt.goal(method=...)`), next to the paper's z = B(g) in the same run.

The target protocol's goal suite (the named poses, 4 episodes each, half fall starts, the clips' states as the
other half) on each evaluation seed, once per method, with the same starts: only the goal's z differs.
lab/log.md section 48 chose the default with it.

    python lab/experiments/goal_inference.py pretrained --seeds 72 73 --methods backward states mix --threads 1

`--fall-prob 0` (clip starts only) and `--fall-prob 1` (fall starts only) split goal success by where it starts.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from fbcpr.inference.agents import make_agent
from fbcpr.eval.report import json_safe
from fbcpr.eval.runner import EPISODE_STEPS, TEST_FALL_PROB, evaluate
from fbcpr.inference.prompt import GOAL_METHODS


class GoalMethodAgent:
    """A BFM whose goal prompts use one inference method; everything else is the model's own."""

    def __init__(self, bfm: Any, method: str) -> None:
        self.bfm, self.method = bfm, method

    def __getattr__(self, name: str) -> Any:
        return getattr(self.bfm, name)

    def goal_z(self, goal: Any) -> np.ndarray:
        return self.bfm.prompt.goal(goal, method=self.method)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agent", help="checkpoint dir or 'pretrained'")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--methods", nargs="+", default=list(GOAL_METHODS), choices=GOAL_METHODS)
    ap.add_argument("--motions", default="data/clips/deepmimic", help="folder of the training clips (.npz)")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--fall-prob", type=float, default=TEST_FALL_PROB, help="share of fall starts (protocol: 0.5)")
    ap.add_argument("--threads", type=int, help="torch and MuJoCo threads; 1 beside a training")
    ap.add_argument("--out", type=Path, help="write per-seed, per-pose results as JSON here")
    args = ap.parse_args()
    if args.threads is not None:
        import torch

        torch.set_num_threads(args.threads)
    from motions.library import MotionLibrary

    motions = MotionLibrary.load(args.motions)
    bfm = make_agent(args.agent)
    if not hasattr(bfm, "prompt"):
        raise SystemExit(f"{args.agent}: goal inference methods apply to a promptable model (FB-CPR)")
    methods = ["backward"] + [m for m in args.methods if m != "backward"]  # the reference always runs
    results: dict[str, dict[int, dict[str, Any]]] = {m: {} for m in methods}
    for seed in args.seeds:
        for method in methods:
            t0 = time.perf_counter()
            res = evaluate(GoalMethodAgent(bfm, method), "goal", episodes=args.episodes, motions=motions,
                           steps=args.steps, fall_prob=args.fall_prob, seed=seed, show_progress=False,
                           num_threads=args.threads)
            results[method][seed] = {"success": res["summary"]["goal"]["success"],
                                     "proximity": res["summary"]["goal"]["proximity"],
                                     "poses": {g: r["success"] for g, r in res["goal"].items()}}
            print(f"seed {seed} {method:>8}: success {results[method][seed]['success']:.3f}  proximity "
                  f"{results[method][seed]['proximity']:.3f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    base = np.array([results["backward"][s]["success"] for s in args.seeds])
    print(f"\n{'method':>8}  mean success  proximity  vs backward  seeds higher / lower")
    for method in methods:
        succ = np.array([results[method][s]["success"] for s in args.seeds])
        prox = np.mean([results[method][s]["proximity"] for s in args.seeds])
        print(f"{method:>8}  {succ.mean():12.3f}  {prox:9.3f}  {succ.mean() - base.mean():+11.3f}  "
              f"{int((succ > base).sum())} / {int((succ < base).sum())}")
    if args.out is not None:
        args.out.write_text(json.dumps(json_safe({"agent": args.agent, "episodes": args.episodes, "steps": args.steps,
                                                  "fall_prob": args.fall_prob, "results": results}), indent=1))


if __name__ == "__main__":
    main()
