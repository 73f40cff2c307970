"""Reuse of an NPMP decoder as a frozen low-level controller (paper Sec. 4.3, Fig. 6): a high-level agent acts in
the latent space, through the AR(1) prior.

`LatentActionEnv` wraps any of our batched envs. Its action a in [-1, 1]^d is the prior's innovation, scaled:
eps_t = scale * a_t and z_t = alpha z_{t-1} + sqrt(1 - alpha^2) eps_t (Eq. 2 with the noise chosen by the agent),
and the decoder's mean action mu(s_t, z_t) steps the wrapped env. z_{t-1} is part of the Markov state, so the
observation is [s_t, z_{t-1}]; every episode starts at z = 0 (the prior's mode, as the encoder's recursion does).
With eps = 0 the latent decays toward 0, and uniform random actions at scale sqrt(3) draw eps with the prior's
unit variance, so a warm-up of random actions explores like samples of the prior.

`latent_bundle` swaps an `EnvBundle` for the wrapped one (`env.npmp` in the run config), so the trainer and
single-task agents (TD3) run unchanged; its task rewards read the env part of the observation.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space

from fbcpr.apps.npmp.checkpoint import load_npmp
from fbcpr.apps.npmp.model import NPMPModel, prior_params
from fbcpr.core.checkpoint import CheckpointError
from fbcpr.core.errors import ConfigError, InputError
from fbcpr.core.protocols import EnvBundle, TaskReward
from fbcpr.core.schema import EnvConfig
from fbcpr.eval.rollout import Step, rollout


class LatentActionEnv(VectorWrapper):
    """A VectorEnv whose actions are scaled AR(1) innovations of an NPMP latent and whose observations are
    [env observation, previous latent]. Simulator state (qpos, qvel, step counters) is the wrapped env's."""

    def __init__(self, env: VectorEnv, model: NPMPModel, scale: float) -> None:
        super().__init__(env)
        if scale <= 0:
            raise InputError(f"scale: must be > 0, got {scale}")
        self.model, self.scale = model, float(scale)
        self.alpha = float(model.cfg.alpha)
        self.env_obs_dim, d = model.obs_dim, model.z_dim
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (d,), np.float32)
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (self.env_obs_dim + d,), np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.z = np.zeros((self.num_envs, d), np.float32)         # z_{t-1} of every env
        self._env_obs = np.zeros((self.num_envs, self.env_obs_dim), np.float32)

    def __getattr__(self, name: str) -> Any:
        if name == "env":  # not set yet (during construction or unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    def save_state(self) -> dict[str, np.ndarray]:
        """The wrapped env's state (`save_state`) with this wrapper's: the previous latent z_{t-1} of every env and the
        env observation the decoder reads next, so a resumed run goes on exactly."""
        inner: Any = self.env  # a batched env of `fbcpr.envs` (humanoid or toy), which saves its own state
        return {**inner.save_state(), "latent_z": self.z.copy(), "latent_env_obs": self._env_obs.copy()}

    def load_state(self, state: dict[str, np.ndarray]) -> np.ndarray:
        """Restore what `save_state` gave; returns the observation ([env observation, previous latent])."""
        for key, like in (("latent_z", self.z), ("latent_env_obs", self._env_obs)):
            if key not in state or tuple(np.shape(state[key])) != like.shape:
                raise InputError(f"env state: {key!r} must have shape {like.shape}")
        inner: Any = self.env
        inner.load_state({k: v for k, v in state.items() if not k.startswith("latent_")})
        self.z = np.array(state["latent_z"], np.float32)
        self._env_obs = np.array(state["latent_env_obs"], np.float32)
        return self._observe(self._env_obs, self.z)

    def _observe(self, env_obs: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(env_obs, np.float32), z], -1)

    def latent(self, actions: np.ndarray) -> np.ndarray:
        """z_t = alpha z_{t-1} + sqrt(1 - alpha^2) scale a_t for actions (num_envs, d), clipped to [-1, 1]."""
        a = np.asarray(actions, np.float32)
        if a.shape != (self.num_envs, self.model.z_dim) or not np.isfinite(a).all():
            raise InputError(f"actions: expected finite shape ({self.num_envs}, {self.model.z_dim}), got {a.shape}")
        mean, std = prior_params(torch.as_tensor(self.z), self.alpha)
        return (mean.numpy() + std * self.scale * np.clip(a, -1.0, 1.0)).astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(seed=seed, options=options)
        self.z[:] = 0.0
        self._env_obs = np.asarray(obs, np.float32)
        return self._observe(obs, self.z), info

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Decode z_t at the current state, step the env; `final_obs` carries z_t, a new episode starts at z = 0.
        info["env_action"] holds the decoder's actions."""
        z = self.latent(actions)
        low = self.model.act(torch.as_tensor(self._env_obs), torch.as_tensor(z)).cpu().numpy()
        obs, reward, terminated, truncated, info = self.env.step(low)
        info = {**info, "final_obs": self._observe(info["final_obs"], z), "env_action": low}
        self.z = np.where(np.asarray(terminated | truncated)[:, None], 0.0, z).astype(np.float32)
        self._env_obs = np.asarray(obs, np.float32)
        return self._observe(obs, self.z), reward, terminated, truncated, info


def load_decoder(path: str, bundle: EnvBundle, cfg: EnvConfig) -> NPMPModel:
    """The frozen NPMP of checkpoint `path`, checked against the env; ConfigError naming env.npmp otherwise."""
    try:
        ckpt = load_npmp(path)
    except (CheckpointError, OSError) as err:
        raise ConfigError(f"env.npmp: {path}: cannot load an NPMP checkpoint ({err})") from None
    model = ckpt.model.requires_grad_(False)
    for key, have in (("obs_dim", bundle.obs_dim), ("action_dim", bundle.action_dim)):
        if getattr(model, key) != have:
            raise ConfigError(f"env.npmp: {path} was distilled with {key} {getattr(model, key)}, the {cfg.name} env "
                              f"has {have}")
    mapping = ckpt.info.get("action_mapping")
    if cfg.name == "humanoid" and mapping is not None and mapping != cfg.action_mapping:
        raise ConfigError(f"env.npmp: {path} was distilled under action mapping {mapping!r}, env.action_mapping is "
                          f"{cfg.action_mapping!r}")
    return model


def latent_bundle(bundle: EnvBundle, cfg: EnvConfig) -> EnvBundle:
    """`bundle` with its training and evaluation envs acting through the NPMP of `cfg.npmp`."""
    assert cfg.npmp is not None, "latent_bundle needs env.npmp"
    model = load_decoder(cfg.npmp, bundle, cfg)
    scale, n = cfg.npmp_innovation_scale, bundle.obs_dim

    def task_reward(name: str) -> TaskReward:
        inner = bundle.task_reward(name)
        return lambda next_obs, qpos, qvel: inner(next_obs[:, :n], qpos, qvel)

    return replace(bundle, env=LatentActionEnv(bundle.env, model, scale), obs_dim=n + model.z_dim,
                   action_dim=model.z_dim, task_reward=task_reward,
                   make_eval_env=lambda k, steps: LatentActionEnv(bundle.make_eval_env(k, steps), model, scale))


def task_return(act: Callable[[np.ndarray], np.ndarray], bundle: EnvBundle, task: str, episodes: int, steps: int,
                seed: int = 0) -> dict[str, float]:
    """Mean undiscounted return of `task` over `episodes` episodes of `steps` steps of a policy act(obs) -> actions
    from the env's initial states (the learning-curve metric), and how much the env's actions change per step
    (mean ||a_t - a_{t-1}||: jerky control is large; the decoder's actions when acting through an NPMP)."""
    reward, env = bundle.task_reward(task), bundle.make_eval_env(episodes, steps + 1)
    try:
        obs, _ = env.reset(seed=seed)
        total, executed = np.zeros(episodes), []

        def watch(step: Step) -> None:
            info = step.info
            total[:] += np.asarray(reward(info["final_obs"], info["final_qpos"], info["final_qvel"]))
            executed.append(np.asarray(info.get("env_action", step.action)))

        rollout(env, obs, lambda t, o: act(np.asarray(o, np.float32)), steps, watch)
        change = float(np.linalg.norm(np.diff(np.stack(executed).astype(np.float64), axis=0), axis=-1).mean(-1).sum())
    finally:
        env.close()
    return {"return": float(total.mean()), "action_change": change / max(steps - 1, 1)}
