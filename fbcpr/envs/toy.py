"""A 2-D point with demonstrations: a seconds-scale stand-in for the humanoid in tests and benchmarks.

State: position p in [-1, 1]^2. Action a in [-1, 1]^2 moves it: p' = clip(p + 0.1 a) (kinematic control, so every
behaviour is about positions and learns in CPU minutes). Observation = qpos = (x, y); qvel is the last displacement
(kept for the qpos/qvel interface, not observed). The batched env mirrors `VectorHumanoidEnv`'s API (SAME_STEP
autoreset, info["qpos"/"qvel"], info["final_obs"/"final_qpos"/"final_qvel"], "_final_obs"). The demonstration library
mirrors `motions.MotionLibrary` (windows, states, EMD priorities), and the tasks are rewards on the next observation,
like the humanoid's reward registry.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import EnvBundle, TaskReward
from fbcpr.core.schema import EnvConfig
from motions.library import matching_names, priorities_from_emd

OBS_DIM, ACTION_DIM, NQ, NV = 2, 2, 2, 2
STEP = 0.1
EPISODE_STEPS = 100

#: Reward on next observations (N, 2) -> (N,) in [0, 1].
ToyReward = Callable[[np.ndarray], np.ndarray]


def _tolerance(dist: np.ndarray, margin: float) -> np.ndarray:
    return np.exp(-0.5 * (dist / margin) ** 2)


TASKS: dict[str, ToyReward] = {
    "reach-top-right": lambda o: _tolerance(np.linalg.norm(o[:, :2] - np.array([0.6, 0.6]), axis=1), 0.15),
    "left-wall": lambda o: (o[:, 0] < -0.7).astype(np.float64),
    "ring": lambda o: _tolerance(np.abs(np.linalg.norm(o[:, :2], axis=1) - 0.5), 0.08),
    "bottom-strip": lambda o: ((o[:, 1] < -0.5) & (np.abs(o[:, 0]) < 0.3)).astype(np.float64),
}
GOALS = np.array([[0.6, 0.6], [-0.6, 0.6], [0.0, -0.7], [-0.5, -0.5], [0.7, -0.2]])


def get_task(name: str) -> ToyReward:
    if name not in TASKS:
        raise KeyError(f"unknown toy task {name!r}; known: {sorted(TASKS)}")
    return TASKS[name]


def observe(qpos: np.ndarray, qvel: np.ndarray | None = None) -> np.ndarray:
    """The observation of states: the position (qvel is not observed)."""
    return np.asarray(qpos, dtype=np.float32)


def dynamics(qpos: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One batched step: new positions and the displacements actually made."""
    p = np.clip(qpos + STEP * np.clip(action, -1.0, 1.0), -1.0, 1.0)
    return p, p - qpos


class UniformInit:
    """Positions uniformly in [-0.9, 0.9]^2 (the toy's 'fall' init: includes states no demonstration visits)."""

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        return rng.uniform(-0.9, 0.9, size=(n, NQ)), np.zeros((n, NV))


class MixtureInit:
    """Uniform init with probability fall_prob, demonstration states otherwise."""

    def __init__(self, fall_prob: float, demos: DemoLibrary | None) -> None:
        self.fall_prob, self.demos, self.uniform = (fall_prob if demos is not None else 1.0), demos, UniformInit()

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        qpos, qvel = self.uniform.sample(rng, n)
        use_demo = rng.random(n) >= self.fall_prob
        if self.demos is not None and use_demo.any():
            dq, dv = self.demos.sample_states(rng, int(use_demo.sum()))
            qpos[use_demo], qvel[use_demo] = dq, dv
        return qpos, qvel


class PointMassVectorEnv(VectorEnv):
    """num_envs point masses stepped together in numpy."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, num_envs: int, init: Any | None = None, reward: ToyReward | str | None = None,
                 max_episode_steps: int = EPISODE_STEPS) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs, self.max_episode_steps = num_envs, max_episode_steps
        self.init = init if init is not None else UniformInit()
        self.reward_fn = get_task(reward) if isinstance(reward, str) else reward
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._np_random, _ = seeding.np_random(None)
        self.qpos, self.qvel = np.zeros((num_envs, NQ)), np.zeros((num_envs, NV))
        self.steps = np.zeros(num_envs, dtype=np.int64)

    def _obs(self) -> np.ndarray:
        return observe(self.qpos)

    def get_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of (qpos, qvel, steps into the episode) of every env, as the humanoid's batched env gives them."""
        return self.qpos.copy(), self.qvel.copy(), self.steps.copy()

    def set_episode_steps(self, steps: np.ndarray) -> None:
        self.steps[:] = steps

    def save_state(self) -> dict[str, np.ndarray]:
        """Everything the next steps depend on (the point mass has no more than its state and step counters)."""
        return {"qpos": self.qpos.copy(), "qvel": self.qvel.copy(), "steps": self.steps.copy()}

    def load_state(self, state: dict[str, np.ndarray]) -> np.ndarray:
        """Restore what `save_state` gave; returns the observation (ValueError naming a missing or mis-shaped
        entry)."""
        for key, shape in (("qpos", self.qpos.shape), ("qvel", self.qvel.shape), ("steps", self.steps.shape)):
            if key not in state or tuple(np.shape(state[key])) != shape:
                raise ValueError(f"env state: {key!r} must have shape {shape}")
        self.qpos, self.qvel = np.array(state["qpos"], np.float64), np.array(state["qvel"], np.float64)
        self.steps[:] = state["steps"]
        return self._obs()

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            self._np_random, _ = seeding.np_random(int(seed))
        if options and "qpos" in options:
            self.qpos = np.array(options["qpos"], dtype=np.float64).reshape(self.num_envs, NQ)
            self.qvel = np.array(options.get("qvel", np.zeros((self.num_envs, NV))),
                                 dtype=np.float64).reshape(self.num_envs, NV)
        else:
            self.qpos, self.qvel = self.init.sample(self.np_random, self.num_envs)
        self.steps[:] = 0
        return self._obs(), {"qpos": self.qpos.copy(), "qvel": self.qvel.copy()}

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, ACTION_DIM):
            raise ValueError(f"actions must have shape ({self.num_envs}, {ACTION_DIM}), got {a.shape}")
        self.qpos, self.qvel = dynamics(self.qpos, a)
        obs = self._obs()
        reward = self.reward_fn(obs) if self.reward_fn is not None else np.zeros(self.num_envs)
        self.steps += 1
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = self.steps >= self.max_episode_steps
        info: dict[str, Any] = {"final_obs": obs.copy(), "final_qpos": self.qpos.copy(), "final_qvel": self.qvel.copy(),
                                "_final_obs": truncated.copy()}
        ids = np.flatnonzero(truncated)
        if len(ids):
            self.qpos[ids], self.qvel[ids] = self.init.sample(self.np_random, len(ids))
            self.steps[ids] = 0
            obs = self._obs()
        info["qpos"], info["qvel"] = self.qpos.copy(), self.qvel.copy()
        return obs, np.asarray(reward, dtype=np.float64), terminated, truncated, info


def demo_paths(length: int = 200) -> dict[str, np.ndarray]:
    """Observation-only demonstrations (T, 2): circles, a figure eight and two sweeps (steps < 0.1: feasible)."""
    t = np.arange(length, dtype=np.float64)
    w = 0.04 / 0.5
    paths = {
        "circle-ccw": 0.5 * np.stack([np.cos(w * t), np.sin(w * t)], 1),
        "circle-cw-small": np.array([0.3, -0.2]) + 0.3 * np.stack([np.cos(-0.1 * t), np.sin(-0.1 * t)], 1),
        "figure-eight": np.stack([0.6 * np.sin(0.05 * t), 0.4 * np.sin(0.1 * t)], 1),
        "sweep-top": np.stack([0.8 * np.sin(0.05 * t), np.full(length, 0.6)], 1),
        "sweep-left": np.stack([np.full(length, -0.6), 0.8 * np.sin(0.05 * t + 1.0)], 1),
    }
    return {k: v.astype(np.float32) for k, v in paths.items()}


class DemoLibrary:
    """Demonstrations with the motion library's sampling API (observation windows, states, priorities)."""

    def __init__(self, demos: dict[str, np.ndarray]) -> None:
        self.names = list(demos)
        self.clips = [demos[n] for n in self.names]
        self.lengths = np.array([len(c) for c in self.clips])
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        self._obs = np.concatenate(self.clips).astype(np.float32)
        self.priorities = np.ones(len(self.clips))

    @property
    def frames(self) -> np.ndarray:
        """Every demonstration's observations, concatenated (demonstration m's begin at row offsets[m])."""
        return self._obs

    def __len__(self) -> int:
        return len(self.clips)

    def set_priorities_from_emd(self, emd: dict[str, float]) -> None:
        missing = sorted(set(self.names) - set(emd))
        if missing:
            raise ValueError(f"set_priorities_from_emd: missing names {missing}")
        self.priorities = priorities_from_emd(np.array([emd[n] for n in self.names]))

    def _pick(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.choice(len(self.clips), size=n, p=self.priorities / self.priorities.sum())

    def sample_windows(self, rng: np.random.Generator, n: int, length: int) -> np.ndarray:
        return self.sample_window_clips(rng, n, length)[0]

    def sample_window_clips(self, rng: np.random.Generator, n: int, length: int) -> tuple[np.ndarray, np.ndarray]:
        m = self._pick(rng, n)
        start = (rng.random(n) * (self.lengths[m] - length + 1)).astype(int)
        return self._obs[(self.offsets[m] + start)[:, None] + np.arange(length)[None]], m

    def matching(self, patterns: Sequence[str]) -> np.ndarray:
        return matching_names(self.names, patterns)

    def sample_states(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        m = self._pick(rng, n)
        obs = self._obs[self.offsets[m] + (rng.random(n) * self.lengths[m]).astype(int)].astype(np.float64)
        return obs, np.zeros((n, NV))


def state_observer() -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The toy's observation of a state (its position): reward samples stored as states are rebuilt with it."""
    return observe


def toy_bundle(cfg: EnvConfig, num_envs: int, threads: int | None = None) -> EnvBundle:
    """The point mass with its demonstrations (`env.name: toy`); `threads` is unused (it steps in numpy)."""

    def task_reward(name: str) -> TaskReward:
        try:
            fn = get_task(name)
        except KeyError as err:
            raise ConfigError(f"agent.reward.task: {err.args[0]}") from None
        return lambda next_obs, qpos, qvel: fn(next_obs)

    demos = demo_paths()
    names = list(demos) if cfg.motions == "synthetic" else [n.strip() for n in cfg.motions.split(",")]
    unknown = [n for n in names if n not in demos]
    if unknown:
        raise ConfigError(f"env.motions: unknown toy demonstration {unknown[0]!r}; give 'synthetic' (all) or "
                          f"comma-separated names of {sorted(demos)}")
    lib = DemoLibrary({n: demos[n] for n in names})
    init = MixtureInit(cfg.fall_prob, lib)

    def pos_err(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.linalg.norm(a[:, :2] - b[:, :2], axis=-1)

    return EnvBundle(
        env=PointMassVectorEnv(num_envs, init=init, max_episode_steps=cfg.max_episode_steps),
        library=lib, obs_dim=OBS_DIM, action_dim=ACTION_DIM, nq=NQ, nv=NV,
        make_eval_env=lambda n, steps: PointMassVectorEnv(n, max_episode_steps=steps),
        clip_obs=lambda i: lib.clips[i],
        clip_start=lambda i: (lib.clips[i][0].astype(np.float64), np.zeros(NV)),
        # mean position error in units of 0.1, so the paper's EMD bins [0.5, 5] span 0.05-0.5 of the arena
        emd=lambda a, b: float(10.0 * pos_err(a, b).mean()),
        success=lambda a, b: bool((pos_err(a, b) <= 0.1).all()),
        task_reward=task_reward,
    )
