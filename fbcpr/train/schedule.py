"""The schedule of a run: rollout phases split over data-parallel ranks at one process's update-to-data ratio, and
periodic jobs carried over a resume."""
from __future__ import annotations

import math

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import Config, TrainConfig


def phase_steps(tc: TrainConfig, world_size: int) -> int:
    """Vector-env steps each rank takes per rollout phase: rollout_steps global env steps shared by the ranks."""
    return max(1, math.ceil(tc.rollout_steps / (tc.num_envs * world_size)))


def check_world_size(cfg: Config, world_size: int) -> None:
    """ConfigError unless `world_size` ranks run `cfg` at the update-to-data ratio of one process: a phase must
    collect as many global env steps as one process collects (ranks x phase_steps x num_envs); an exact resume
    (train.save_buffer) holds for one process only (the other ranks' replay shards are not saved)."""
    if world_size <= 1:
        return
    tc = cfg.train
    single = phase_steps(tc, 1)
    if phase_steps(tc, world_size) * world_size != single:
        fits = [w for w in range(1, single + 1) if phase_steps(tc, w) * w == single]
        raise ConfigError(f"train.rollout_steps: {tc.rollout_steps} env steps per phase with train.num_envs: "
                          f"{tc.num_envs} envs per rank do not split over {world_size} ranks without changing the "
                          f"update-to-data ratio; world sizes that fit: {fits}")
    if tc.save_buffer:
        raise ConfigError(f"train.save_buffer: an exact resume needs one process, and {world_size} ranks were "
                          "launched (only rank 0 writes checkpoints); set it to false")


def rescheduled(saved: float, every: int, env_steps: int) -> float:
    """The next env step of a periodic job after a resume whose config may change its period: 0 turns it off, and
    one switched on starts at the next multiple of its period; otherwise the saved schedule goes on."""
    if not every:
        return math.inf
    return saved if math.isfinite(saved) else (env_steps // every + 1) * every


