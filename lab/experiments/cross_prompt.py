"""Which half of a continued model lost a skill: one model's actor under another model's prompts.

    python lab/experiments/cross_prompt.py runs/M-best pretrained --suite goal --seed 0 --motions data/clips/deepmimic

A run warm-started from a model changes both its B (the prompts: z = B(goal), the ER_FB of a clip's windows,
the reward-weighted mean of B) and its actor. This evaluates the ACTOR model acting on the PROMPTER model's z's,
next to each model on its own, with the same starts. If the crossed row matches the prompter's own, the actor
still follows those z's and the drift of B lost the skill; if it matches the actor's own, the actor lost it.
Only two models of one lineage (one continued from the other) share a z-space; for others the crossed row is
meaningless. lab/log.md section 25 uses it on a continuation of the shipped model.
"""
from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from fbcpr.inference.bfm import BFM, check_compatible
from fbcpr.eval.runner import EPISODE_STEPS, SUITES, evaluate


class CrossedAgent:
    """Acts with `actor`'s policy on the latents that `prompter` infers (an `fbcpr.eval.agents.Agent`)."""

    def __init__(self, actor: BFM, prompter: BFM) -> None:
        check_compatible(actor, prompter, f"cross {actor.source} with {prompter.source}", same_networks=False)
        self.actor, self.prompter = actor, prompter
        self.action_mapping = actor.action_mapping
        self.name = f"{actor.source} acting on {prompter.source}'s prompts"

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        return self.actor.act(obs, z, mean=mean)

    def reward_z(self, reward: Any) -> np.ndarray:
        return self.prompter.reward_z(reward)

    def goal_z(self, goal_obs: np.ndarray) -> np.ndarray:
        return self.prompter.goal_z(goal_obs)

    def track_z(self, obs_seq: np.ndarray) -> np.ndarray:
        return self.prompter.track_z(obs_seq)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("actor", help="checkpoint whose policy acts")
    ap.add_argument("prompter", help="checkpoint whose B turns prompts into z ('pretrained' for the shipped model)")
    ap.add_argument("--suite", choices=(*SUITES, "all"), default="goal")
    ap.add_argument("--motions", default="data/clips/deepmimic", help="clips: test starts, and tracked clips")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None, help="torch and MuJoCo threads (1 beside a training)")
    args = ap.parse_args()
    from motions.library import MotionLibrary

    actor, prompter = BFM.load(args.actor), BFM.load(args.prompter)
    motions = MotionLibrary.load(args.motions)
    rows = {"actor's own": actor, "prompter's own": prompter, "crossed": CrossedAgent(actor, prompter)}
    for name, agent in rows.items():
        res = evaluate(agent, args.suite, episodes=args.episodes, motions=motions, steps=args.steps, seed=args.seed,
                       show_progress=False, num_threads=args.threads)
        print(f"{name:>15}: {json.dumps(res['summary'])}", flush=True)


if __name__ == "__main__":
    main()
