"""The one loop that rolls a policy out on an env: benchmark episodes, tracking during training, upright probes,
the toy's measures, NPMP reuse and the prompt CLI all step through it and only say what they watch."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np


class Step(NamedTuple):
    """One env step as a watcher sees it: the step index t, the action taken, and what the env returned."""

    t: int
    action: np.ndarray
    obs: np.ndarray
    reward: Any
    info: dict[str, Any]


def rollout(env: Any, obs: np.ndarray, act: Callable[[int, np.ndarray], np.ndarray], steps: int,
            watch: Callable[[Step], bool | None]) -> int:
    """Step `env` from `obs` (what its reset returned) for `steps` steps: a_t = act(t, obs_t), then
    `watch(step)`, which ends the rollout early by returning True. Returns the number of steps taken."""
    for t in range(steps):
        action = act(t, obs)
        obs, reward, _, _, info = env.step(action)
        if watch(Step(t, action, obs, reward, info)):
            return t + 1
    return steps
