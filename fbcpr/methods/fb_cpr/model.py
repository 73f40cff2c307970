"""FBCPRModel: everything needed to act and to prompt (normalizer, F, B, actor, Q critic, discriminator).

The public inference methods (`act`, `backward`, `project_z`, `sample_z`) accept torch tensors or numpy
arrays and return the same kind; they run without gradients. Training code uses the sub-networks directly
on normalized observations (`normalize`).
"""
from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch
from torch import Tensor, nn

from fbcpr.core.errors import InputError
from fbcpr.core.schema import ModelConfig
from fbcpr.nn.networks import BackwardNet, Discriminator, ZConditionedNet, noisy_action, project_sphere
from fbcpr.nn.normalizer import RunningNormalizer

ArrayLike = TypeVar("ArrayLike", Tensor, np.ndarray)


class FBCPRModel(nn.Module):
    """The networks of Algorithm 1 with the sizes of a `ModelConfig` (obs_dim and action_dim must be set)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        if cfg.obs_dim is None or cfg.action_dim is None:
            raise ValueError("ModelConfig.obs_dim and action_dim must be set before building a model")
        self.cfg = cfg
        o, a, d, h, m = cfg.obs_dim, cfg.action_dim, cfg.z_dim, cfg.hidden_dim, cfg.ensemble_size
        self.obs_normalizer = RunningNormalizer(o, cfg.norm_eps, cfg.norm_obs)
        self.forward_map = ZConditionedNet(o, a, d, d, h, cfg.hidden_layers, cfg.embedding_layers, m)
        self.backward_map = BackwardNet(o, d, cfg.backward_hidden_dim, cfg.backward_hidden_layers)
        self.actor = ZConditionedNet(o, 0, d, a, h, cfg.hidden_layers, cfg.embedding_layers, 1)
        self.critic = ZConditionedNet(o, a, d, 1, h, cfg.hidden_layers, cfg.embedding_layers, m)
        self.discriminator = Discriminator(o, d, cfg.discriminator_hidden_dim, cfg.discriminator_hidden_layers)

    @property
    def device(self) -> torch.device:
        return self.obs_normalizer.mean.device

    @property
    def z_dim(self) -> int:
        return self.cfg.z_dim

    # ------------------------------------------------------------------ training-side helpers (with grad)
    def normalize(self, obs: Tensor) -> Tensor:
        return self.obs_normalizer(obs)

    def actor_mean(self, obs_n: Tensor, z: Tensor) -> Tensor:
        """tanh mean of the Gaussian policy at normalized observations."""
        return torch.tanh(self.actor(obs_n, None, z)[0])

    def actor_sample(self, obs_n: Tensor, z: Tensor, generator: torch.Generator | None = None,
                     noise: Tensor | None = None) -> Tensor:
        """mean + clipped N(0, std^2) noise (`noise`: standard normal draws made beforehand, else drawn from
        `generator`), clamped to [-1, 1] with a straight-through gradient."""
        return noisy_action(self.actor_mean(obs_n, z), self.cfg.actor_std, self.cfg.actor_noise_clip, generator,
                            noise)

    # ------------------------------------------------------------------ public inference API
    @torch.no_grad()
    def act(self, obs: ArrayLike, z: ArrayLike, mean: bool = True,
            generator: torch.Generator | None = None) -> ArrayLike:
        """Action (N, action_dim) in [-1, 1] for raw observations (N, obs_dim) and latents (N, z_dim)."""
        obs_t, z_t = self._in(obs), self._in(z)
        self._check(obs_t, self.cfg.obs_dim, "obs")
        self._check(z_t, self.cfg.z_dim, "z")
        obs_n = self.normalize(obs_t)
        a = self.actor_mean(obs_n, z_t) if mean else self.actor_sample(obs_n, z_t, generator)
        return a.cpu().numpy() if isinstance(obs, np.ndarray) else a

    @torch.no_grad()
    def backward(self, obs: ArrayLike) -> ArrayLike:
        """B of normalized observations: (N, obs_dim) -> (N, z_dim), on the sqrt(d) sphere."""
        obs_t = self._in(obs)
        self._check(obs_t, self.cfg.obs_dim, "obs")
        b = self.backward_map(self.normalize(obs_t))
        return b.cpu().numpy() if isinstance(obs, np.ndarray) else b

    def project_z(self, z: ArrayLike) -> ArrayLike:
        """Project latents onto the sqrt(d) sphere."""
        if isinstance(z, np.ndarray):
            return project_sphere(torch.as_tensor(z, dtype=torch.float32)).numpy()
        return project_sphere(z)

    def sample_z(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """n latents uniform on the sqrt(d) sphere."""
        g = torch.randn(n, self.cfg.z_dim, generator=generator, device=self.device)
        return project_sphere(g)

    def _in(self, x: ArrayLike) -> Tensor:
        t = torch.as_tensor(x, device=self.device)
        return t.float() if t.dtype != torch.float32 else t

    @staticmethod
    def _check(x: Tensor, dim: int | None, name: str) -> None:
        if x.dim() != 2 or x.shape[1] != dim:
            raise InputError(f"{name}: expected shape (N, {dim}), got {tuple(x.shape)}")
