"""ProgressReward: pays for reaching later frames of the demonstrations, as an `ImitationReward` (not in the papers).

r(s') = max_j p_j exp(-d_smpl(s', f_j) / scale) over every frame f_j of the env's clips, with p_j = (j + 1) / T the
frame's place in its clip of T frames. Nothing is learnt: it is fixed, dense and has no phase, so it can pay from
any start. It was written for getting up: along the getup clip a pose pays more the further up the rise it lies,
a body lying as the clip starts earns almost nothing, and the risen end pays the most.
Where an adversarial reward saturates within thousands of updates on one short clip (docs/results-imitation.md),
this one keeps its gradient toward the next frames. It is no tracking reward: a pose near a late frame pays the
same whichever way it got there.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import POSITIVE, _f
from humanoid_env.observation import POSE

#: At most this many demonstration frames: each reward call compares every state with every frame.
MAX_FRAMES = 20_000


@dataclass
class ProgressConfig:
    """The `agent.progress:` section."""

    # d_smpl over which the pay falls by e: poses of one rise lie 2-5 apart 10 frames (1/3 s) on, and our standing
    # rest pose is 3.9 from the getup clip's last frame
    scale: float = _f(3.0, POSITIVE)


class ProgressReward:
    """The frames' pose parts and their progress, on the device."""

    def __init__(self, obs_dim: int, cfg: ProgressConfig, device: str | torch.device = "cpu", seed: int = 0,
                 library: Any = None) -> None:
        """`library`: the env's clips (a `motions.library.MotionLibrary`); `seed` is unused (nothing is drawn)."""
        if library is None:
            raise ConfigError("agent.reward.imitation: progress needs the env's demonstration clips (env.motions)")
        frames = sum(int(c.n_frames) for c in library.clips)
        if frames > MAX_FRAMES:
            raise ConfigError(f"agent.reward.imitation: progress compares every state with every frame; env.motions "
                              f"holds {frames:,} frames, at most {MAX_FRAMES:,} (give the clips to imitate only)")
        self.cfg, self.device = cfg, torch.device(device)
        poses = np.concatenate([c.obs[:, POSE] for c in library.clips])
        progress = np.concatenate([np.arange(1, c.n_frames + 1) / c.n_frames for c in library.clips])
        self.poses = torch.as_tensor(poses, dtype=torch.float32, device=self.device)
        self.progress = torch.as_tensor(progress, dtype=torch.float32, device=self.device)

    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """Nothing to fit: the reward is fixed by the clips."""
        return {}

    @torch.no_grad()
    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> Tensor:
        """(n,) rewards of the next states: their best progress-weighted closeness to a frame."""
        dist = torch.cdist(next_obs.to(self.device, torch.float32)[:, POSE], self.poses)
        return (self.progress * torch.exp(-dist / self.cfg.scale)).amax(1)

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        return {}, {}

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        """Nothing saved: a resumed run rebuilds the reward from the same clips."""
