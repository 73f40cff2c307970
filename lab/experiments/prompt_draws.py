"""How much a reward prompt depends on which states it is inferred from: draws of a model's own states.

Each DRAW is a run of `fbcpr/configs/own-states.yaml` from the same model (a different `train.seed`), whose checkpoint
holds one sample of that model's own states. For every named task this prints how close (cosine) the z of one draw
is to another draw's (the reference: what two shipped samples differ by), and to the z regressed on all draws
pooled, which `fbcpr export --store-prompts` stores; and the z's of two disjoint halves of the draws, pooled each,
to each other (how stable a stored prompt would be). lab/log.md section 43.

    python lab/experiments/prompt_draws.py runs/anch/soup-AG runs/own/AG-roll runs/own/AG-roll2 runs/cache/roll-s{9..16}
"""
from __future__ import annotations

import argparse
import itertools

import numpy as np
import torch

from fbcpr import BFM
from fbcpr.inference.reward_prompts import infer_reward_prompts
from humanoid_env.tasks.rewards import TASKS


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def pooled(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="the model whose prompts are inferred (its B)")
    ap.add_argument("draws", nargs="+", help="checkpoints or runs whose reward samples are the draws (at least 4)")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS))
    args = ap.parse_args()
    if len(args.draws) < 4:
        ap.error("give at least 4 draws (two halves of 2 or more)")
    torch.set_num_threads(1)
    bfm = BFM.load(args.model)
    draws = [BFM.load(d).reward_buffer for d in args.draws]
    half = len(draws) // 2
    sets = {"all": pooled(draws), "A": pooled(draws[:half]), "B": pooled(draws[half:2 * half])}
    sets.update({i: d for i, d in enumerate(draws)})
    # each set's prompts as `fbcpr export --store-prompts` infers them; a task a set pays nothing on is left out
    prompts = {name: infer_reward_prompts(BFM(bfm.model, bfm.config, reward_buffer=s), args.tasks).z
               for name, s in sets.items()}
    print(f"{args.model}: {len(draws)} draws of {[len(d['qpos']) for d in draws]} states; halves of {half} draws")
    print(f"{'task':>22s} {'draw-draw mean':>15s} {'min':>6s} {'draw-pooled mean':>17s} {'halves':>7s}")
    rows = []
    for task in args.tasks:
        if any(task not in p for p in prompts.values()):
            print(f"{task:>22s} skipped: it pays nothing on some draw's states")
            continue
        z = {name: p[task] for name, p in prompts.items()}
        pairs = [cosine(z[i], z[j]) for i, j in itertools.combinations(range(len(draws)), 2)]
        to_pool = [cosine(z[i], z["all"]) for i in range(len(draws))]
        row = (float(np.mean(pairs)), float(np.min(pairs)), float(np.mean(to_pool)), cosine(z["A"], z["B"]))
        rows.append(row)
        print(f"{task:>22s} {row[0]:15.3f} {row[1]:6.3f} {row[2]:17.3f} {row[3]:7.3f}")
    m = np.mean(rows, axis=0)
    print(f"{'mean over ' + str(len(rows)) + ' tasks':>22s} {m[0]:15.3f} {m[1]:6.3f} {m[2]:17.3f} {m[3]:7.3f}")


if __name__ == "__main__":
    main()
