"""How long the humanoid stays up under the stand prompt: the plainest learning signal for a humanoid controller.

Two measures, from standing starts and from fall starts (one episode per env, no auto-reset within):
- seconds until the pelvis first drops below `FALLEN` (0.6 m) from a standing start;
- whether the pelvis stays above `STANDING` (0.8 m) over the whole last second from a fall start (got up).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fbcpr.eval.agents import action_mapping
from fbcpr.eval.rollout import Step, rollout
from fbcpr.eval.runner import EPISODE_STEPS  # 300 steps: 10 s
from humanoid_env.env import FALLEN_HEIGHT
from humanoid_env.model import CONTROL_HZ

FALLEN, STANDING = FALLEN_HEIGHT, 0.8
STAND_PROMPT = "move-ego-0-0"
#: a pushed standing start (`DefaultInit` joint-angle noise in rad, velocity noise) that topples the zero action
PUSH = (0.1, 0.3)


@dataclass
class Upright:
    """Per-episode results: seconds upright from standing starts, got up (bool) from fall starts."""

    seconds: np.ndarray
    got_up: np.ndarray

    @property
    def median_seconds(self) -> float:
        return float(np.median(self.seconds))

    @property
    def share_got_up(self) -> float:
        return float(np.mean(self.got_up))


def pelvis_heights(agent: Any, init: Any, episodes: int, steps: int, seed: int,
                   prompt: str | np.ndarray = STAND_PROMPT, num_threads: int | None = None) -> np.ndarray:
    """Pelvis heights (steps, episodes) of the agent prompted with `prompt` (a reward name, or a z) from `init`
    starts, stepped on `num_threads` threads (None: all cores)."""
    from humanoid_env.vector import VectorHumanoidEnv

    env = VectorHumanoidEnv(episodes, init=init, max_episode_steps=steps + 1, action_mapping=action_mapping(agent),
                            num_threads=num_threads)
    try:
        obs, _ = env.reset(seed=seed)
        z = agent.reward_z(prompt) if isinstance(prompt, str) else np.asarray(prompt, dtype=np.float32)
        z = np.broadcast_to(z, (episodes, agent.z_dim))
        heights = np.empty((steps, episodes))

        def watch(step: Step) -> None:
            heights[step.t] = step.obs[:, 0]

        rollout(env, obs, lambda t, o: agent.act(o, z), steps, watch)
    finally:
        env.close()
    return heights


def seconds_upright(heights: np.ndarray) -> np.ndarray:
    """Per episode, seconds until the pelvis first drops below `FALLEN` (the whole episode if it never does)."""
    fallen = heights < FALLEN
    return np.where(fallen.any(0), fallen.argmax(0), heights.shape[0]) / CONTROL_HZ


def got_up(heights: np.ndarray) -> np.ndarray:
    """Per episode, whether the pelvis stayed above `STANDING` over the whole last second."""
    return np.asarray((heights[-CONTROL_HZ:] > STANDING).all(0))


def fall_starts_got_up(agent: Any, episodes: int, steps: int, seed: int, prompt: str | np.ndarray = STAND_PROMPT,
                       num_threads: int | None = None) -> np.ndarray:
    """Per episode, whether a fall start got up under `prompt`; the fall starts of `seed` are drawn with seed + 1,
    so they are not the same draws as the standing starts of that seed."""
    from humanoid_env.inits import FallInit

    return got_up(pelvis_heights(agent, FallInit(), episodes, steps, seed + 1, prompt, num_threads=num_threads))


def upright_medians(agent: Any, episodes: int, steps: int = EPISODE_STEPS, seed: int = 0) -> dict[str, float]:
    """What a training run logs at each evaluation (`train.eval_upright`): median seconds upright under the stand
    prompt from standing starts (`upright_s`, which the zero action holds) and from pushed ones (`upright_pushed_s`,
    where it falls), and the share of fall starts that got up (`got_up`), the same starts every time."""
    from humanoid_env.inits import DefaultInit

    out = {key: float(np.median(seconds_upright(pelvis_heights(agent, init, episodes, steps, seed))))
           for key, init in (("upright_s", DefaultInit()), ("upright_pushed_s", DefaultInit(*PUSH)))}
    return out | {"got_up": float(np.mean(fall_starts_got_up(agent, episodes, steps, seed)))}


def upright(agent: Any, episodes: int = 16, steps: int = EPISODE_STEPS, seed: int = 0,
            num_threads: int | None = None) -> Upright:
    """Both measures for one agent (a BFM or a floor baseline), `episodes` each, seeded."""
    from humanoid_env.inits import DefaultInit

    h = pelvis_heights(agent, DefaultInit(), episodes, steps, seed, num_threads=num_threads)
    return Upright(seconds=seconds_upright(h), got_up=fall_starts_got_up(agent, episodes, steps, seed,
                                                                         num_threads=num_threads))
