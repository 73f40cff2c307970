"""How far a continued model's actions moved from the model it started from, prompt by prompt.

    python lab/experiments/action_drift.py pretrained runs/NR/checkpoints/step_0000020480 runs/NR/checkpoints/step_0000360448 \
        --tasks split-1 sitonground move-ego-0-2 --episodes 1 --seed 0

The BASE model is rolled out under each task's reward prompt (its own z, from its own reward sample), and on the
states it visits every other model is asked for its action under the same z. Each cell is the mean squared
difference per action component. The reference column, measured in the same run, is the base's own exploration
noise on those states (sampled action against its mean, ~actor_std^2): a drift well below it is a change smaller
than the noise the base was trained with. lab/log.md section 27 uses it on continuations of the shipped
model (one z for every model, so a drift of the prompts themselves does not enter; see cross_prompt.py for that).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from fbcpr.inference.bfm import BFM, check_compatible
from fbcpr.eval.runner import EPISODE_STEPS


def rollout_states(base: BFM, z: np.ndarray, episodes: int, steps: int, seed: int) -> np.ndarray:
    """Observations (n, obs_dim) the base visits under z, from the env's default starts of seeds seed, seed + 1..."""
    from humanoid_env.env import HumanoidEnv

    env, states = HumanoidEnv(action_mapping=base.action_mapping), []
    for ep in range(episodes):
        obs, _ = env.reset(seed=seed + ep)
        for _ in range(steps):
            states.append(obs)
            obs, _, terminated, truncated, _ = env.step(base.act(obs, z))
            if terminated or truncated:
                break
    return np.asarray(states, dtype=np.float32)


def drift(base: BFM, models: list[BFM], tasks: list[str], episodes: int, steps: int,
          seed: int) -> dict[str, dict[str, float]]:
    """Per task: the base's exploration noise ("noise") and each model's mean squared action change (by index)."""
    gen = torch.Generator().manual_seed(seed)
    out: dict[str, dict[str, float]] = {}
    for task in tasks:
        z = base.prompt.reward(task)
        obs = rollout_states(base, z, episodes, steps, seed)
        zs = np.repeat(z[None], len(obs), 0)
        ref = base.act(obs, zs)
        row = {"noise": float(((base.act(obs, zs, mean=False, generator=gen) - ref) ** 2).mean())}
        for i, model in enumerate(models):
            row[str(i)] = float(((model.act(obs, zs) - ref) ** 2).mean())
        out[task] = row
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", help="the model the others continued from ('pretrained' for the shipped model)")
    ap.add_argument("models", nargs="+", help="checkpoints continued from the base")
    ap.add_argument("--tasks", nargs="+", default=["split-1", "sitonground", "move-ego-0-0", "move-ego-0-2"])
    ap.add_argument("--episodes", type=int, default=1, help="base rollouts per task")
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    base = BFM.load(args.base)
    models = [BFM.load(m) for m in args.models]
    for spec, model in zip(args.models, models):
        check_compatible(model, base, f"compare {spec} with {args.base}", same_networks=False)
    res = drift(base, models, args.tasks, args.episodes, args.steps, args.seed)
    width = max(map(len, args.tasks))
    print(f"{'model':60s} " + " ".join(f"{t:>{width}s}" for t in args.tasks))
    print(f"{'reference: the base, sampled against its mean':60s} " + " ".join(f"{res[t]['noise']:>{width}.2e}"
                                                                               for t in args.tasks))
    for i, spec in enumerate(args.models):
        print(f"{spec[-60:]:60s} " + " ".join(f"{res[t][str(i)]:>{width}.2e}" for t in args.tasks), flush=True)


if __name__ == "__main__":
    main()
