"""Share of training steps with the body up, with and without `env.reset_fallen_s`.

A replay buffer can only teach balance from upright states. Rollouts from the training init mixture (MoCap
states, fall with probability `--fall-prob`) under N(0, sigma^2) actions stand in for a young policy; the script
counts the steps whose pelvis is above the fallen line (0.6 m) with each reset setting, in the same run.

    python lab/experiments/fall_reset_share.py --motions data/clips/mixed --seconds 0 0.5 1 2
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from humanoid_env.env import FALLEN_HEIGHT, reset_fallen_steps
from humanoid_env.inits import make_init
from humanoid_env.vector import VectorHumanoidEnv
from motions.library import MotionLibrary


def upright_share(library: MotionLibrary, seconds: float, sigma: float, fall_prob: float, envs: int, steps: int,
                  seed: int) -> tuple[float, int]:
    """(share of env steps with the pelvis above the fallen line, episodes ended) over `steps` steps of `envs` envs."""
    env = VectorHumanoidEnv(envs, init=make_init(fall_prob, mocap=library), action_mapping="rest",
                            reset_fallen_after=reset_fallen_steps(seconds))
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    up = ended = 0
    try:
        for _ in range(steps):
            _, _, term, trunc, info = env.step(rng.normal(0.0, sigma, (envs, 69)))  # the env clips to [-1, 1]
            up += int((info["final_qpos"][:, 2] > FALLEN_HEIGHT).sum())
            ended += int((term | trunc).sum())
    finally:
        env.close()
    return up / (envs * steps), ended


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--motions", required=True, help="a folder of clips (.npz) for the MoCap init")
    p.add_argument("--seconds", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0])
    p.add_argument("--sigma", type=float, default=0.2, help="std of the Gaussian actions")
    p.add_argument("--fall-prob", type=float, default=0.2)
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--steps", type=int, default=600, help="env steps per setting (episodes are 300 steps)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    library = MotionLibrary.load(a.motions)
    print(f"{len(library.names)} clips, sigma {a.sigma}, fall_prob {a.fall_prob}, {a.envs} envs x {a.steps} steps")
    print("reset_fallen_s | share upright | episodes | s")
    for seconds in a.seconds:
        t = time.perf_counter()
        share, ended = upright_share(library, seconds, a.sigma, a.fall_prob, a.envs, a.steps, a.seed)
        print(f"{seconds:14.2f} | {share:13.3f} | {ended:8d} | {time.perf_counter() - t:.1f}")


if __name__ == "__main__":
    main()
