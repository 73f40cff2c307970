"""TD3Model: observation normaliser, deterministic actor pi(s) and ensemble critic Q(s, a).

Both are the paper's "simple MLP" (Table 5: layernorm + tanh after the first layer, ReLU after the others) built
from the same batched-ensemble `Stack` as FB-CPR's networks; `model.hidden_dim` / `hidden_layers` size them.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from fbcpr.core.errors import InputError
from fbcpr.core.schema import ModelConfig
from fbcpr.nn.networks import Stack, noisy_action
from fbcpr.nn.normalizer import RunningNormalizer


class TD3Model(nn.Module):
    """A single-task policy and its critic; `act` takes raw observations (numpy or torch) and ignores z."""

    z_dim = 0

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.obs_dim is None or cfg.action_dim is None:
            raise ValueError("ModelConfig.obs_dim and action_dim must be set before building a model")
        self.cfg = cfg
        o, a, h, n, m = cfg.obs_dim, cfg.action_dim, cfg.hidden_dim, cfg.hidden_layers, cfg.ensemble_size
        self.obs_normalizer = RunningNormalizer(o, cfg.norm_eps, cfg.norm_obs)
        self.actor = Stack([o] + [h] * n + [a], 1, final=None)
        self.critic = Stack([o + a] + [h] * n + [1], m, final=None)

    @property
    def device(self) -> torch.device:
        return self.obs_normalizer.mean.device

    def normalize(self, obs: Tensor) -> Tensor:
        return self.obs_normalizer(obs)

    def actor_mean(self, obs_n: Tensor, detach_params: bool = False) -> Tensor:
        return torch.tanh(self.actor(obs_n, detach_params)[0])

    def actor_sample(self, obs_n: Tensor, generator: torch.Generator | None = None) -> Tensor:
        return noisy_action(self.actor_mean(obs_n), self.cfg.actor_std, self.cfg.actor_noise_clip, generator)

    def q(self, obs_n: Tensor, action: Tensor, detach_params: bool = False) -> Tensor:
        """(members, n) Q values at normalized observations."""
        return self.critic(torch.cat([obs_n, action], -1), detach_params)[..., 0]

    @torch.no_grad()
    def act(self, obs: Tensor | np.ndarray, z: Tensor | np.ndarray | None = None, mean: bool = True,
            generator: torch.Generator | None = None) -> Tensor | np.ndarray:
        """Actions (N, action_dim) in [-1, 1] for raw observations (N, obs_dim); z is accepted and ignored."""
        obs_t = torch.as_tensor(obs, dtype=torch.float32, device=self.device)
        if obs_t.dim() != 2 or obs_t.shape[1] != self.cfg.obs_dim:
            raise InputError(f"obs: expected shape (N, {self.cfg.obs_dim}), got {tuple(obs_t.shape)}")
        obs_n = self.normalize(obs_t)
        a = self.actor_mean(obs_n) if mean else self.actor_sample(obs_n, generator)
        return a.cpu().numpy() if isinstance(obs, np.ndarray) else a
