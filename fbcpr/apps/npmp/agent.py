"""One-shot tracking with an NPMP as an evaluation `Agent` (`fbcpr.eval.agents`): `track_z` encodes the
reference into one latent per step (open loop in z, paper Sec. 3.2) and `act` runs the decoder (closed loop in the
state). An NPMP has no reward or goal prompt: those raise PromptError, which the runner records as skipped."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from fbcpr.apps.npmp.checkpoint import load_npmp
from fbcpr.core.errors import InputError, PromptError
from fbcpr.inference.prompt import motion_observations
from humanoid_env.actions import DEFAULT_ACTION_MAPPING


class NPMPAgent:
    """A loaded NPMP checkpoint that tracks clips; `info` is its npmp.json (expert, method, steps, ...)."""

    def __init__(self, path: str | Path, device: str | torch.device = "cpu", name: str | None = None) -> None:
        ckpt = load_npmp(path, device)
        self.model, self.info, self.path = ckpt.model, ckpt.info, ckpt.path
        self.name = name or str(path)
        self.action_mapping: str = str(self.info.get("action_mapping", DEFAULT_ACTION_MAPPING))

    @property
    def z_dim(self) -> int:
        return self.model.z_dim

    @property
    def obs_dim(self) -> int:
        return self.model.obs_dim

    def act(self, obs: Any, z: Any, mean: bool = True) -> np.ndarray:
        """Decoder mean actions (N, action_dim) for obs (N, obs_dim) or (obs_dim,) and z (N, d) or (d,)."""
        o, zt = torch.as_tensor(np.asarray(obs, np.float32)), torch.as_tensor(np.asarray(z, np.float32))
        if o.dim() not in (1, 2) or o.shape[-1] != self.obs_dim:
            raise InputError(f"obs: expected shape ({self.obs_dim},) or (N, {self.obs_dim}), got {tuple(o.shape)}")
        single, o = o.dim() == 1, o.reshape(-1, self.obs_dim)
        if zt.dim() not in (1, 2) or zt.shape[-1] != self.z_dim or (zt.dim() == 2 and zt.shape[0] not in (1, len(o))):
            raise InputError(f"z: expected shape ({self.z_dim},) or ({len(o)}, {self.z_dim}), got {tuple(zt.shape)}")
        zt = zt.reshape(-1, self.z_dim).expand(o.shape[0], -1)
        a = self.model.act(o, zt).cpu().numpy()
        return a[0] if single else a

    def track_z(self, obs_seq: Any) -> np.ndarray:
        """(T-1, d) encoder means for a reference motion (Clip, clip file or (T, obs_dim) observations)."""
        obs = motion_observations(obs_seq, self.obs_dim, min_length=2)
        return self.model.encode(torch.as_tensor(obs)).cpu().numpy()

    def reward_z(self, reward: Any) -> np.ndarray:
        raise PromptError("an NPMP model has no reward prompt: it tracks reference motions")

    def goal_z(self, goal_obs: Any) -> np.ndarray:
        raise PromptError("an NPMP model has no goal prompt: it tracks reference motions")
