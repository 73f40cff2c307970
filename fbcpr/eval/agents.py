"""What the benchmark evaluates: any object with `act` plus the three prompt functions.

Built in: the floor baselines RandomAgent and ZeroAgent (they ignore z). A loaded `fbcpr.BFM` is an Agent as it is; an
NPMP checkpoint is an `fbcpr.apps.npmp.agent.NPMPAgent` (tracking only); a single-task checkpoint (TD3, on a task or an
imitation reward) is wrapped as a `SingleTaskAgent`, which is evaluated on its own task. Later baselines plug in by
offering the same methods.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np

from fbcpr.core.errors import InputError
from humanoid_env.actions import DEFAULT_ACTION_MAPPING
from humanoid_env.model import NU
from humanoid_env.observation import OBS_DIM


class Actor(Protocol):
    """What a rollout needs of a policy: act(obs (N,358), z (N,d), mean) -> actions (N,69), anything array-like."""

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> Any: ...


@runtime_checkable
class Agent(Protocol):
    """act(obs (N,358), z (N,d), mean) -> actions (N,69) in [-1,1]; prompts map tasks to latent vectors (each
    agent names its prompt's argument its own way, so the protocol takes it by position)."""

    @property
    def z_dim(self) -> int: ...

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray: ...

    def reward_z(self, reward: str | Callable[..., np.ndarray], /) -> np.ndarray: ...

    def goal_z(self, goal_obs: np.ndarray, /) -> np.ndarray: ...

    def track_z(self, obs_seq: np.ndarray, /) -> np.ndarray: ...


class _Floor:
    """A z-free baseline: prompts return an empty z, so every task gets the same behaviour."""

    z_dim = 0
    name = "floor"

    def reward_z(self, reward: str | Callable[..., np.ndarray]) -> np.ndarray:
        return np.zeros(0, np.float32)

    def goal_z(self, goal_obs: np.ndarray) -> np.ndarray:
        _check_obs(goal_obs, "goal_z")
        return np.zeros(0, np.float32)

    def track_z(self, obs_seq: np.ndarray) -> np.ndarray:
        seq = np.asarray(obs_seq)
        if seq.ndim != 2 or seq.shape[1] != OBS_DIM:
            raise InputError(f"track_z: expected (T, {OBS_DIM}) observations, got {seq.shape}")
        return np.zeros((len(seq), 0), np.float32)


def _check_obs(obs: np.ndarray, who: str) -> np.ndarray:
    arr = np.asarray(obs)
    if arr.shape[-1] != OBS_DIM:
        raise InputError(f"{who}: expected observations with last dimension {OBS_DIM}, got {arr.shape}")
    return arr


class RandomAgent(_Floor):
    """Uniform random actions in [-1, 1]^69 (seeded)."""

    name = "random"

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        n = _check_obs(obs, "act").reshape(-1, OBS_DIM).shape[0]
        return self.rng.uniform(-1.0, 1.0, (n, NU)).astype(np.float32)


class ZeroAgent(_Floor):
    """Action 0: under the default mapping, every PD target at the standing rest pose."""

    name = "zero"

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        n = _check_obs(obs, "act").reshape(-1, OBS_DIM).shape[0]
        return np.zeros((n, NU), np.float32)


class SingleTaskAgent(_Floor):
    """A trained single-task policy (any non-prompt-able method of `fbcpr.core.registry`): it acts without z, so every
    prompt returns an empty one; `task` and `imitation` say what it was trained on (its own evaluation)."""

    def __init__(self, model: Any, config: Any, name: str) -> None:
        self.model, self.name = model, name
        reward = config.agent.reward
        self.task: str | None = reward.task
        self.imitation: str | None = reward.imitation
        self.action_mapping: str = config.env.action_mapping

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        arr = _check_obs(obs, "act").reshape(-1, OBS_DIM)
        return self.model.act(np.asarray(arr, dtype=np.float32), mean=mean)


def action_mapping(agent: object) -> str:
    """The env action mapping an agent's actions are meant for (`humanoid_env.actions`); floors use the default."""
    return str(getattr(agent, "action_mapping", DEFAULT_ACTION_MAPPING))
