"""A continuation with B frozen, judged under the stored prompts of the model it continued from.

    python lab/experiments/carry_prompts.py CAND pretrained --out runs/s57/cand-p \
        [--refine crouch-0=Z.npy --generations 5 --starts 8 --seed 3]

A run with `agent.freeze_backward` keeps B and the observation normaliser of the model it started from, and
`fbcpr export --reward-states-from BASE` gives it BASE's reward states, so every zero-shot reward prompt of the
continued model is BASE's. BASE's stored prompts (its refined ones too) then answer for the continued actor; the
export drops them only because they belong to other weights (their digest). This script checks that the two models
share B, the normaliser and the reward states, takes BASE's stored prompts for CAND, optionally refines named tasks
for CAND's own actor from given z's (`fbcpr.inference.reward_prompts.refine_reward_prompts`, as `fbcpr export
--refine-prompts --refine-from` does), and saves the result as an inference checkpoint. BASE's refined z's were
searched for BASE's actor, not CAND's: the record says so (lab/log.md 57).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.inference.refine import Search
from fbcpr.inference.reward_prompts import refine_reward_prompts, weights_digest

#: the parts of the model that every reward prompt's z depends on
PROMPT_PARTS = ("backward_map.", "obs_normalizer.")


def shared_prompting(cand: BFM, base: BFM) -> list[str]:
    """Why CAND's zero-shot prompts would differ from BASE's (empty when they cannot)."""
    reasons = []
    ours, theirs = cand.model.state_dict(), base.model.state_dict()
    for name, t in theirs.items():
        if name.startswith(PROMPT_PARTS) and not torch.equal(t, ours.get(name, torch.empty(0))):
            reasons.append(f"{name} differs")
    a, b = cand.reward_buffer, base.reward_buffer
    if a is None or b is None or not np.array_equal(np.asarray(a["qpos"]), np.asarray(b["qpos"])):
        reasons.append("the reward states differ (export CAND with --reward-states-from BASE)")
    return reasons


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("candidate")
    ap.add_argument("base")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--refine", nargs="*", default=[], metavar="TASK=Z.npy")
    ap.add_argument("--generations", type=int, default=5)
    ap.add_argument("--population", type=int, default=16)
    ap.add_argument("--starts", type=int, default=8)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    cand, base = BFM.load(args.candidate), BFM.load(args.base)
    if base.reward_prompts is None:
        raise SystemExit(f"{args.base}: has no stored reward prompts to carry")
    reasons = shared_prompting(cand, base)
    if reasons:
        raise SystemExit(f"{args.candidate} does not prompt as {args.base}: " + "; ".join(reasons))
    cand.reward_prompts = replace(base.reward_prompts, digest=weights_digest(cand.model))
    starts: dict[str, np.ndarray] = {}
    for item in args.refine:
        task, sep, path = item.partition("=")
        if not sep:
            raise SystemExit(f"--refine {item!r}: give TASK=Z.npy")
        starts[task] = np.load(path)
    if starts:
        search = Search(generations=args.generations, population=args.population, seed=args.seed)
        cand.reward_prompts = refine_reward_prompts(cand, list(starts), search, args.starts, args.steps,
                                                    start_from=starts)
        for task in starts:
            rec = cand.reward_prompts.refined[task]
            print(f"{task}: mean reward per step {rec['score0']:.3f} at the start z -> {rec['score']:.3f} refined")
    cand.save(args.out, half=True, states_only=True)
    print(f"saved {args.out}: {args.base}'s stored prompts"
          + (f", {', '.join(starts)} refined for {args.candidate}" if starts else ""))


if __name__ == "__main__":
    main()
