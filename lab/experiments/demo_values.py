"""What a TD3 checkpoint's critic thinks the demonstrations it trained on are worth, next to what they return.

    python lab/experiments/demo_values.py runs/bc-s0/checkpoints/step_0000320512

A critic that bootstraps where it has seen only the demonstrator's actions can overrate the policy's nearby ones;
the gap then returns along each demonstration in the TD target, times 1 / (1 - discount) (lab/log.md
section 33). This prints, at five steps along the demonstrations of the run's `train.demonstrations`: their discounted
return under the run's reward (the reward of their last 20 steps held after the end, as they end standing),
Q(s, demonstrated action) and Q(s, policy's action); then Q(s, policy's action) on the policy's own states from
the run's starts, next to the reward it collects there.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import torch

from fbcpr.core.checkpoint import CheckpointError, load_checkpoint
from fbcpr.core.schema import Config
from fbcpr.train.trainer import Trainer


def discounted_returns(reward: np.ndarray, discount: float, tail: int = 20) -> np.ndarray:
    """(demos, T) returns of each step, the mean reward of the last `tail` steps held forever after the end."""
    acc = reward[:, -tail:].mean(1) / (1.0 - discount)
    out = np.empty_like(reward)
    for t in range(reward.shape[1] - 1, -1, -1):
        acc = reward[:, t] + discount * acc
        out[:, t] = acc
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint")
    ap.add_argument("--online-steps", type=int, default=4800, help="env steps of the policy's own states")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    try:
        cfg = load_checkpoint(args.checkpoint).config
    except CheckpointError as err:
        raise SystemExit(str(err)) from None
    if not isinstance(cfg, Config) or cfg.algorithm != "td3" or not cfg.train.demonstration_share:
        raise SystemExit(f"{args.checkpoint}: needs a TD3 run with demonstrations held apart (train.demonstration_share)")
    cfg.train.warmup_steps = cfg.train.total_env_steps  # collect the policy's states, never update
    cfg.train.eval_every = cfg.train.checkpoint_every = 0
    with tempfile.TemporaryDirectory() as out:
        tr = Trainer(cfg, Path(out), progress=False, init_from=args.checkpoint)
        try:
            model, agent, demos = tr.agent.model.eval(), tr.agent, tr.learner.demos
            lengths = np.diff(np.flatnonzero(np.r_[True, ~demos["demo_next"].numpy()[:-1], True]))
            if len(set(lengths)) != 1:
                raise SystemExit("the demonstrations differ in length; this reads them as one (demos, T) table")
            shape = (len(lengths), int(lengths[0]))
            with torch.no_grad():
                reward = agent.reward(demos).numpy().reshape(shape)
                obs_n = model.normalize(demos["obs"])
                a_pi = model.actor_mean(obs_n)
                q_demo = model.q(obs_n, demos["action"]).mean(0).numpy().reshape(shape)
                q_pi = model.q(obs_n, a_pi).mean(0).numpy().reshape(shape)
                mse = (a_pi - demos["action"]).square().mean().item()
            ret = discounted_returns(reward, cfg.agent.discount)
            print(f"{shape[0]} demonstrations of {shape[1]} steps; policy vs demonstrated action: mse {mse:.4f}")
            print("| demonstration step | return | Q(s, demonstrated a) | Q(s, policy's a) |\n|---:|---:|---:|---:|")
            for t in np.unique(np.linspace(0, shape[1] - 1, 5).astype(int)):
                print(f"| {t} | {ret[:, t].mean():.1f} | {q_demo[:, t].mean():.1f} | {q_pi[:, t].mean():.1f} |")
            tr.run(max_env_steps=args.online_steps)
            batch = tr.buffer.sample(tr.rng, 4096, fields=agent.fields)
            with torch.no_grad():
                o = model.normalize(batch["obs"])
                q_on = model.q(o, model.actor_mean(o)).mean(0)
                r_on = agent.reward(batch).mean().item()
            print(f"policy's own states ({args.online_steps} env steps): Q(s, policy's a) mean {q_on.mean():.1f}, "
                  f"p90 {q_on.quantile(0.9):.1f}; reward {r_on:.3f} per step ({r_on / (1 - cfg.agent.discount):.1f} "
                  "if it held forever)")
        finally:
            tr.close()


if __name__ == "__main__":
    main()
