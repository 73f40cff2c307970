"""Refined prompts against zero-shot ones: what a few minutes of rollouts (`fbcpr.inference.refine`) add to a model.

For each task and refinement seed, z0 (the zero-shot prompt) is refined on MoCap starts drawn with that seed,
then z0 and the refined z are scored, side by side in the same run, on starts the search never saw:
- held out: `--held-out` MoCap starts (no falls), seed 100;
- the target protocol: the evaluation's own test starts (half falls) of `lab/experiments/targets.py`, evaluation seeds
  `--eval-seeds`, `--episodes` each.
Rewards report the return of 300, goals the success and proximity. The search's speed (env steps with the policy,
per second) prints next to the held-out evaluation's, a plain batched rollout measured in the same run.

    python lab/experiments/prompt_refine.py pretrained --tasks move-ego-0-2 --goals t_pose --seeds 0 1 2 \
        --out runs/refine.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.eval.report import json_safe
from fbcpr.eval.runner import evaluate
from fbcpr.inference.refine import Refined, Search, goal_objective, refine, reward_objective
from humanoid_env.inits import make_init
from humanoid_env.tasks import goal_obs

HELD_OUT_SEED = 100


class Prompted:
    """The model with one fixed z in place of its zero-shot prompts (each evaluation below asks one task)."""

    def __init__(self, bfm: BFM, z: np.ndarray) -> None:
        self.bfm, self.z = bfm, np.asarray(z, dtype=np.float32)
        self.z_dim, self.action_mapping = bfm.z_dim, bfm.action_mapping

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> Any:
        return self.bfm.act(obs, z, mean=mean)

    def reward_z(self, reward: Any) -> np.ndarray:
        return self.z

    def goal_z(self, goal: Any) -> np.ndarray:
        return self.z


def score(bfm: BFM, z: np.ndarray, task: str, kind: str, motions: Any, episodes: int, seed: int,
          fall_prob: float | None, args: argparse.Namespace) -> dict[str, float]:
    """One evaluation of z on the task through the benchmark runner (fall_prob None: the test mixture)."""
    extra = {} if fall_prob is None else {"fall_prob": fall_prob}
    res = evaluate(Prompted(bfm, z), kind, tasks=[task], episodes=episodes, motions=motions, steps=args.steps,
                   seed=seed, show_progress=False, num_threads=args.threads, **extra)[kind][task]
    return {"return": res["return_mean"]} if kind == "reward" else {"success": res["success"],
                                                                     "proximity": res["proximity"]}


def run_one(bfm: BFM, task: str, kind: str, motions: Any, args: argparse.Namespace, seed: int) -> dict[str, Any]:
    z0 = bfm.prompt.reward(task) if kind == "reward" else bfm.prompt.goal(task)
    objective = reward_objective(task) if kind == "reward" else goal_objective(goal_obs(task))
    starts = make_init(0.0, motions).sample(np.random.default_rng(1000 + seed), args.starts)
    search = Search(generations=args.generations, population=args.population, seed=seed)
    t0 = time.perf_counter()
    result: Refined = refine(bfm, z0, objective, starts, steps=args.steps, search=search, num_threads=args.threads)
    wall = time.perf_counter() - t0
    row: dict[str, Any] = {"task": task, "kind": kind, "seed": seed, "refine_s": wall, "episodes": result.episodes,
                           "cosine": result.cosine, "train_score0": result.score0, "train_score": result.score,
                           "history": result.history}
    for name, z in (("z0", result.z0), ("refined", result.z)):
        t0 = time.perf_counter()
        row[f"{name}_held_out"] = score(bfm, z, task, kind, motions, args.held_out, HELD_OUT_SEED, 0.0, args)
        row[f"{name}_held_out_s"] = time.perf_counter() - t0
        row[f"{name}_test"] = [score(bfm, z, task, kind, motions, args.episodes, s, None, args)
                               for s in args.eval_seeds]
    return row


def headline(scores: dict[str, float] | list[dict[str, float]], kind: str) -> float:
    key = "return" if kind == "reward" else "success"
    return float(np.mean([s[key] for s in scores])) if isinstance(scores, list) else scores[key]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agent", help="checkpoint dir, run dir or 'pretrained'")
    ap.add_argument("--motions", default="data/clips/deepmimic", help="clip folder: MoCap starts and test starts")
    ap.add_argument("--tasks", nargs="*", default=["move-ego-0-2"], help="reward tasks")
    ap.add_argument("--goals", nargs="*", default=[], help="goal poses")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="refinement seeds (starts and search)")
    ap.add_argument("--generations", type=int, default=10)
    ap.add_argument("--population", type=int, default=16)
    ap.add_argument("--starts", type=int, default=8, help="MoCap starts each candidate is rolled out from")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--held-out", type=int, default=64, help="held-out MoCap starts")
    ap.add_argument("--eval-seeds", nargs="*", type=int, default=[0, 1, 2, 3, 4, 5])
    ap.add_argument("--episodes", type=int, default=4, help="episodes per evaluation seed (targets.py's)")
    ap.add_argument("--threads", type=int, help="torch and MuJoCo threads (default: all cores)")
    ap.add_argument("--out", type=Path, help="write every row (with the search history) as JSON here")
    args = ap.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    from motions.library import MotionLibrary

    bfm = BFM.load(args.agent) if args.agent != "pretrained" else BFM.pretrained()
    motions = MotionLibrary.load(args.motions)
    rows = []
    print(f"{'task':<16}{'seed':>5}{'min':>6}{'cos':>7} | {'held out z0':>11}{'refined':>9} | "
          f"{'test z0':>8}{'refined':>9} | env steps/s: search, reference (z0 held out)")
    for kind, names in (("reward", args.tasks), ("goal", args.goals)):
        for task in names:
            for seed in args.seeds:
                row = run_one(bfm, task, kind, motions, args, seed)
                rows.append(row)
                print(f"{task:<16}{seed:>5}{row['refine_s'] / 60:>6.1f}{row['cosine']:>7.3f} | "
                      f"{headline(row['z0_held_out'], kind):>11.3f}{headline(row['refined_held_out'], kind):>9.3f} | "
                      f"{headline(row['z0_test'], kind):>8.3f}{headline(row['refined_test'], kind):>9.3f} | "
                      f"{row['episodes'] * args.steps / row['refine_s']:,.0f}, "
                      f"{args.held_out * args.steps / row['z0_held_out_s']:,.0f}", flush=True)
                if args.out is not None:
                    args.out.parent.mkdir(parents=True, exist_ok=True)
                    args.out.write_text(json.dumps(json_safe({"settings": vars(args) | {"out": str(args.out)},
                                                              "rows": rows}), indent=1))


if __name__ == "__main__":
    main()
