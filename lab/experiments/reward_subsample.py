"""What a smaller (and float16) reward-inference buffer costs in prompt quality, for a checkpoint that ships.

For each subsample size n, the reward prompt z_n is compared with the z of the checkpoint's whole buffer
(the reference, computed in the same run): cosine similarity over a set of reward tasks, and the episode
return of the prompted policy on a few of them. The float16 row stores the whole buffer as float16 first
(as `fbcpr export --half` does).

    python lab/experiments/reward_subsample.py runs/cpu-rest --sizes 50000 20000 10000 5000 2000
"""
from __future__ import annotations

import argparse
import tempfile

import numpy as np

from fbcpr import BFM
from fbcpr.eval.runner import evaluate

TASKS = ["move-ego-0-0", "move-ego-0-2", "jump-2", "raisearms-l-l", "raisearms-h-h", "crouch-0", "sitonground",
         "lieonground-up", "rotate-z-5-0.8", "split-1"]
RETURN_TASKS = ["move-ego-0-0", "sitonground", "raisearms-l-l"]


class FixedPrompt:
    """An agent that answers reward prompts with zs inferred from its own n-sample buffer."""

    def __init__(self, bfm: BFM, n: int) -> None:
        self.bfm, self.n = bfm, n
        self.action_mapping, self.z_dim, self.name = bfm.action_mapping, bfm.z_dim, f"n={n}"

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        return self.bfm.act(obs, z, mean=mean)

    def reward_z(self, reward: str) -> np.ndarray:
        return self.bfm.prompt.reward(reward, n=self.n)


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20000, 10000, 5000, 2000])
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--steps", type=int, default=150)
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    full = len(bfm.reward_buffer["next_obs"])
    with tempfile.TemporaryDirectory() as tmp:
        half = BFM.load(bfm.save(f"{tmp}/half", half=True))
        half.reward_buffer  # read now: the folder goes away
    models = [(f"{full} fp32", bfm, full), (f"{full} fp16", half, full)] + [(f"{n}", bfm, n) for n in args.sizes]
    ref = {t: bfm.prompt.reward(t, n=full) for t in TASKS}
    print(f"{args.checkpoint}: reference = the whole buffer ({full} states, float32)")
    print(f"{'buffer':>16s} {'MB (fp16)':>10s} {'cos to ref: mean':>17s} {'min':>6s}  "
          + " ".join(f"{t:>14s}" for t in RETURN_TASKS))
    width = sum(v.shape[1] for v in bfm.reward_buffer.values())
    for label, model, n in models:
        cos = [cosine(model.prompt.reward(t, n=n), ref[t]) for t in TASKS]
        res = evaluate(FixedPrompt(model, n), "reward", tasks=RETURN_TASKS, episodes=args.episodes,
                       steps=args.steps, show_progress=False)["reward"]
        print(f"{label:>16s} {n * width * 2 / 2**20:10.1f} {np.mean(cos):17.3f} {np.min(cos):6.3f}  "
              + " ".join(f"{res[t]['return_mean']:14.1f}" for t in RETURN_TASKS))

if __name__ == "__main__":
    main()
