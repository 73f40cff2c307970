"""How long the humanoid stays upright: the plainest learning signal for a humanoid controller.

For each agent (floor baselines and checkpoints), prompted with the stand reward `move-ego-0-0`, it runs
episodes from standing starts (seconds until the pelvis drops below 0.6 m) and from fall starts (share of steps
with the pelvis above 0.8 m, i.e. got up). The zero-action policy, measured in the same run, is the reference.

    python benchmarks/upright_time.py runs/small-deepmimic/checkpoints/step_0000100000 runs/small-deepmimic
"""
from __future__ import annotations

import argparse

import numpy as np

from fbcpr.evaluation.agents import action_mapping, make_agent
from humanoid_env.inits import DefaultInit, FallInit
from humanoid_env.model import CONTROL_HZ
from humanoid_env.vector import VectorHumanoidEnv

FALLEN, STANDING = 0.6, 0.8


def rollout(agent, init, episodes: int, steps: int, seed: int) -> np.ndarray:
    """Pelvis heights (steps, episodes) under the stand prompt; one episode per env, no auto-reset within."""
    env = VectorHumanoidEnv(episodes, init=init, max_episode_steps=steps + 1, action_mapping=action_mapping(agent))
    obs, _ = env.reset(seed=seed)
    z = np.broadcast_to(agent.reward_z("move-ego-0-0"), (episodes, agent.z_dim))
    heights = np.empty((steps, episodes))
    for t in range(steps):
        obs, *_ = env.step(agent.act(obs, z))
        heights[t] = obs[:, 0]
    env.close()
    return heights


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agents", nargs="*", help="checkpoint dirs or run dirs (zero and random are always run)")
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"{'agent':60s} {'upright s (standing start)':>27s} {'got up (fall start)':>20s}")
    for spec in ["zero", "random", *args.agents]:
        agent = make_agent(spec, seed=args.seed)
        h = rollout(agent, DefaultInit(), args.episodes, args.steps, args.seed)
        fell = np.where((h < FALLEN).any(0), (h < FALLEN).argmax(0), args.steps)
        up = rollout(agent, FallInit(), args.episodes, args.steps, args.seed + 1)
        print(f"{spec:60s} {fell.mean() / CONTROL_HZ:20.2f} ± {fell.std() / CONTROL_HZ:4.2f} "
              f"{(up[-args.steps // 3:] > STANDING).mean():20.3f}")


if __name__ == "__main__":
    main()
