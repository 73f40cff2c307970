"""Re-infer some stored reward prompts after their task's reward changed, keeping every other stored prompt.

A stored prompt belongs to the reward it was regressed on. When a task's formula changes (section 52:
`sitonground` gained a head term), its stored z, and its refinement, are stale. This regresses the named tasks
again on the checkpoint's own reward states, the states every other stored prompt was inferred from (refused if
their count differs from the stored prompts' record), drops those tasks' refinement records, records their
formulas' revisions, and writes the checkpoint as `fbcpr export --reward-samples N --half --states-only` does.
Refine them again after with `fbcpr export OUT OUT2 --refine-prompts TASKS`.

    python lab/experiments/reinfer_prompts.py pretrained runs/sit-reinfer --tasks sitonground
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from fbcpr import BFM
from fbcpr.inference.reward_prompts import infer_reward_prompts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("out")
    ap.add_argument("--tasks", required=True, help="comma-separated named tasks to regress again")
    args = ap.parse_args()
    tasks = [t for t in args.tasks.split(",") if t]
    bfm = BFM.load(args.checkpoint)
    stored = bfm.reward_prompts
    if stored is None:
        raise SystemExit(f"{args.checkpoint}: stores no reward prompts")
    states = len(bfm.reward_buffer["next_obs"])
    if states != stored.states:
        raise SystemExit(f"the stored prompts were inferred from {stored.states} states, the checkpoint keeps {states}")
    fresh = infer_reward_prompts(bfm, tasks)
    for task in tasks:
        old, new = stored.zero_shot(task), fresh.z[task]
        print(f"{task}: " + ("no prompt was stored (or it was stale and dropped on load)" if old is None else
                             f"cosine of the new zero-shot z to the stored one "
                             f"{float(np.dot(old, new)) / float(np.linalg.norm(old) * np.linalg.norm(new)):.3f}"))
    bfm.reward_prompts = replace(stored, z={**stored.z, **fresh.z},
                                 refined={t: r for t, r in stored.refined.items() if t not in tasks},
                                 revisions={**{t: r for t, r in stored.revisions.items() if t not in tasks},
                                            **fresh.revisions})
    print("wrote", bfm.save(args.out, reward_samples=states, half=True, states_only=True))


if __name__ == "__main__":
    main()
