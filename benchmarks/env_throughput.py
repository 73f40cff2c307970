"""Env steps per second: one HumanoidEnv and the batched VectorHumanoidEnv, next to raw MuJoCo stepping.

Every case runs the same physics: the same initial state and the same random PD targets, 15 substeps per
control step, a reset every 300 steps. The reference is a bare `mujoco.mj_step(model, data, nstep=15)` loop
(and, for the batched env, a bare `mujoco.batch.Batch.step` on the same threads). Each env runs in lockstep
with its reference on identical states (one control step of each in turn), so both see the same CPU load
from other processes; `--repeats` runs give the best and median figures.

    python benchmarks/env_throughput.py [--steps 300] [--envs 32] [--repeats 7]
"""
from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from humanoid_env.actions import ActionMap
from humanoid_env.env import HumanoidEnv
from humanoid_env.inits import DefaultInit, MocapInit
from humanoid_env.model import N_SUBSTEPS, load_model
from humanoid_env.vector import VectorHumanoidEnv

EPISODE = 300


class _FixedStart:
    """Every episode starts from the same state, so that all cases simulate the same kind of motion."""

    def __init__(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        self.qpos, self.qvel = qpos, qvel

    def sample_states(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        return np.tile(self.qpos, (n, 1)), np.tile(self.qvel, (n, 1))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=300, help="control steps per env per repeat")
    p.add_argument("--envs", type=int, default=32, help="envs in the batched env")
    p.add_argument("--threads", type=int, default=os.cpu_count(), help="threads for the batched env")
    p.add_argument("--repeats", type=int, default=7)
    args = p.parse_args()

    rng = np.random.default_rng(0)
    qpos1, qvel1 = DefaultInit().sample(rng, 1)
    qpos0, qvel0 = np.tile(qpos1, (args.envs, 1)), np.tile(qvel1, (args.envs, 1))
    actions = rng.uniform(-1, 1, (args.steps, args.envs, 69)).astype(np.float32)
    model = load_model()
    ctrl = ActionMap(model).to_ctrl(actions.astype(np.float64))

    data = mujoco.MjData(model)
    env = HumanoidEnv(max_episode_steps=EPISODE)
    batch = mjbatch.Batch(model, args.envs, nthread=args.threads)
    b_qpos, b_qvel, b_ctrl = batch.bind("qpos"), batch.bind("qvel"), batch.bind("ctrl")
    venv = VectorHumanoidEnv(args.envs, init=MocapInit(_FixedStart(qpos1[0], qvel1[0])), num_threads=args.threads,
                             max_episode_steps=EPISODE)
    clock = time.perf_counter

    def lockstep_single() -> tuple[float, float]:
        """Raw stepping and the env, one control step each in turn on identical states: (raw s, env s)."""
        t_raw = t_env = 0.0
        for t in range(args.steps):
            if t % EPISODE == 0:
                mujoco.mj_resetData(model, data)
                data.qpos[:], data.qvel[:] = qpos1[0], qvel1[0]
                env.reset(options={"qpos": qpos1[0], "qvel": qvel1[0]})
            t0 = clock()
            data.ctrl[:] = ctrl[t, 0]
            mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
            t1 = clock()
            env.step(actions[t, 0])
            t_raw, t_env = t_raw + t1 - t0, t_env + clock() - t1
        return t_raw, t_env

    def lockstep_batch() -> tuple[float, float]:
        """Raw Batch.step and the batched env in turn on identical states: (raw s, env s)."""
        t_raw = t_env = 0.0
        for t in range(args.steps):
            if t % EPISODE == 0:
                batch.reset()
                b_qpos[:], b_qvel[:] = qpos0, qvel0
                venv.reset(options={"qpos": qpos0, "qvel": qvel0})  # later resets draw the same fixed state
            t0 = clock()
            b_ctrl[:] = ctrl[t]
            batch.step(nstep=N_SUBSTEPS)
            t1 = clock()
            venv.step(actions[t])
            t_raw, t_env = t_raw + t1 - t0, t_env + clock() - t1
        return t_raw, t_env

    runs = np.array([lockstep_single() + lockstep_batch() for _ in range(args.repeats)])  # (repeats, 4) seconds
    sizes = np.array([args.steps, args.steps, args.steps * args.envs, args.steps * args.envs])
    rate = sizes / runs  # steps/s per repeat
    names = ["raw mj_step", "HumanoidEnv", f"raw Batch.step x{args.envs}", f"VectorHumanoidEnv x{args.envs}"]
    print(f"cores: {os.cpu_count()}, batch threads: {args.threads}, steps per env: {args.steps}, "
          f"repeats: {args.repeats}")
    print(f"{'case':<28}{'steps/s best':>14}{'steps/s median':>16}")
    for i, name in enumerate(names):
        print(f"{name:<28}{rate[:, i].max():>14.0f}{np.median(rate[:, i]):>16.0f}")
    for label, (a, b), target in [
        ("HumanoidEnv / raw mj_step", (1, 0), "(target >= 0.85)"),
        ("VectorHumanoidEnv / HumanoidEnv", (3, 1), f"(target >= 1.7 on 2 cores; {args.threads} threads here)"),
        ("VectorHumanoidEnv / raw Batch.step", (3, 2), ""),
    ]:
        r = rate[:, a] / rate[:, b]  # within a repeat: same load
        print(f"{label:<36} best {r.max():.2f}  median {np.median(r):.2f}  {target}")


if __name__ == "__main__":
    main()
