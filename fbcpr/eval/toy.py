"""Zero-shot evaluation on the point mass: goal reaching, reward maximisation and demo imitation.

The same protocol runs a trained model, an untrained one, or a uniform random policy (model=None), so
their numbers compare like with like. z inference follows App. C.5.3: z = B(goal),
z_r ∝ Σ exp(10 r(s)) r(s) B(s) over reward-labelled states, and z_t ∝ Σ_{j=t+1}^{t+L} B(s_j) for tracking.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fbcpr.envs import toy as pm
from fbcpr.eval.rollout import Step, rollout
from fbcpr.eval.tracking import tracking_latents
from fbcpr.metrics import dtw_pose_error, sparc, speed_profile
from fbcpr.nn.latents import TEMPERATURE, reward_weights
from fbcpr.nn.networks import project_sphere

N_STARTS = 10          # episodes per goal / per task
HORIZON = 100
REWARD_SAMPLES = 20_000
GOAL_RADIUS = 0.2      # 5% of the arena's width
FPS = 30.0             # the toy's nominal control rate, for speeds and SPARC (the humanoid's is 30 Hz too)


def _act(model: Any, obs: np.ndarray, z: torch.Tensor | None, rng: np.random.Generator) -> np.ndarray:
    if model is None:
        return rng.uniform(-1, 1, size=(len(obs), pm.ACTION_DIM))
    return model.act(torch.as_tensor(obs, dtype=torch.float32), z, mean=True).numpy()


def goal_reaching(model: Any, rng: np.random.Generator) -> dict[str, float]:
    """Reach each of pm.GOALS from random states. As in the paper (C.3): success = within 0.2 at any step,
    proximity = fraction of steps within 0.2; plus the distance at the last step."""
    goals = np.repeat(pm.GOALS, N_STARTS, 0)
    env = pm.PointMassVectorEnv(len(goals), max_episode_steps=HORIZON + 1)
    obs, _ = env.reset(seed=int(rng.integers(1 << 31)))
    z = None if model is None else model.backward(torch.as_tensor(goals, dtype=torch.float32))
    dists: list[np.ndarray] = []
    rollout(env, obs, lambda t, o: _act(model, o, z, rng), HORIZON,
            lambda step: dists.append(np.linalg.norm(step.obs[:, :2] - goals, axis=1)))
    d = np.stack(dists, 1)
    return {"goal_final_dist": float(d[:, -1].mean()), "goal_success": float((d < GOAL_RADIUS).any(1).mean()),
            "goal_proximity": float((d < GOAL_RADIUS).mean())}


def reward_z(model: Any, task: str, rng: np.random.Generator, temperature: float = TEMPERATURE) -> torch.Tensor:
    """Weighted-regression z for a task over states spread uniformly over the arena."""
    obs = rng.uniform(-1, 1, size=(REWARD_SAMPLES, pm.OBS_DIM)).astype(np.float32)
    r = torch.as_tensor(pm.get_task(task)(obs), dtype=torch.float32)
    b = model.backward(torch.as_tensor(obs))
    return project_sphere((reward_weights(r, temperature) @ b)[None])


def task_return(model: Any, task: str, rng: np.random.Generator, prompt: bool = True) -> float:
    """Mean episode return (100 steps, reward in [0, 1] per step) of `task` from N_STARTS random states.

    prompt=True infers the task's z first (a prompt-able FB-CPR model); otherwise the policy acts as it is (a
    single-task agent trained on this task, or the random policy when model is None)."""
    env = pm.PointMassVectorEnv(N_STARTS, reward=task, max_episode_steps=HORIZON + 1)
    obs, _ = env.reset(seed=int(rng.integers(1 << 31)))
    z = reward_z(model, task, rng).expand(N_STARTS, -1) if prompt and model is not None else None
    rewards: list[np.ndarray] = []
    rollout(env, obs, lambda t, o: _act(model, o, z, rng), HORIZON, lambda step: rewards.append(step.reward))
    return float(np.sum(rewards, axis=0).mean())


def reward_returns(model: Any, rng: np.random.Generator) -> dict[str, float]:
    """`task_return` of every toy task, zero-shot."""
    return {f"return/{task}": task_return(model, task, rng) for task in pm.TASKS}


def imitation(model: Any, rng: np.random.Generator, seq_length: int = 8) -> dict[str, float]:
    """Track each demonstration from its first state: mean position error and fraction of steps within 0.1."""
    demos = pm.demo_paths()
    errs = {}
    for name, ref in demos.items():
        env = pm.PointMassVectorEnv(1, max_episode_steps=len(ref) + 1)
        obs, _ = env.reset(options={"qpos": ref[:1], "qvel": np.zeros((1, pm.NV))})
        zs = None if model is None else tracking_latents(model, ref, seq_length)
        err = np.empty(len(ref) - 1)

        def act(t: int, o: np.ndarray, zs: torch.Tensor | None = zs) -> np.ndarray:
            return _act(model, o, None if zs is None else zs[t: t + 1], rng)

        def watch(step: Step, ref: np.ndarray = ref, err: np.ndarray = err) -> None:
            err[step.t] = np.linalg.norm(step.obs[0, :2] - ref[step.t + 1, :2])

        rollout(env, obs, act, len(ref) - 1, watch)
        errs[name] = err
    all_err = np.concatenate(list(errs.values()))
    return {"track_error": float(all_err.mean()), "track_within_0.1": float((all_err < 0.1).mean()),
            **{f"track_error/{k}": float(v.mean()) for k, v in errs.items()}}


def demo_rollouts(model: Any, demo: str, rng: np.random.Generator) -> np.ndarray:
    """(N_STARTS, T, 2) paths of a policy that acts without a prompt (model=None: random) from the demo's first
    state, for the demo's length T."""
    ref = pm.demo_paths()[demo]
    env = pm.PointMassVectorEnv(N_STARTS, max_episode_steps=len(ref) + 1)
    obs, _ = env.reset(options={"qpos": np.repeat(ref[:1], N_STARTS, 0), "qvel": np.zeros((N_STARTS, pm.NV))})
    traj = [obs]
    rollout(env, obs, lambda t, o: _act(model, o, None, rng), len(ref) - 1, lambda step: traj.append(step.obs))
    return np.stack(traj, 1)


def shape_coverage(path: np.ndarray, ref: np.ndarray, radius: float = 0.1) -> float:
    """Share of the demonstration's points (T, 2) that the path (T', 2) comes within `radius` of, in any order:
    how much of the demo's shape is reproduced (a point standing still on the demo covers a few percent)."""
    d = np.linalg.norm(ref[:, None, :2] - path[None, :, :2], axis=-1)
    return float((d.min(1) <= radius).mean())


def imitation_metrics(model: Any, demo: str, rng: np.random.Generator, fps: float = FPS) -> dict[str, float]:
    """NEAR's imitation metrics for a policy that acts without a prompt (model=None: random), from the demo's first
    state for its length: average DTW position error to the demo, SPARC of the speed next to the demo's, and the
    share of the demo's shape reproduced."""
    ref = pm.demo_paths()[demo]
    paths = demo_rollouts(model, demo, rng)
    return {"dtw": float(np.mean([dtw_pose_error(p, ref) for p in paths])),
            "sparc": float(np.mean([sparc(speed_profile(p, fps), fps) for p in paths])),
            "sparc_expert": sparc(speed_profile(ref, fps), fps),
            "shape_coverage": float(np.mean([shape_coverage(p, ref) for p in paths]))}


def evaluate(model: Any, seed: int = 0, seq_length: int = 8) -> dict[str, float]:
    """All three zero-shot protocols; model=None evaluates a uniform random policy."""
    rng = np.random.default_rng(seed)
    if model is not None:
        model.eval()
    return {**goal_reaching(model, rng), **reward_returns(model, rng), **imitation(model, rng, seq_length)}
