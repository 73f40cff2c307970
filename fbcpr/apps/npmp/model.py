"""The NPMP networks (paper Sec. 2.2, App. B): encoder q(z_t | z_{t-1}, x_t), AR(1) prior p(z_t | z_{t-1}) and
decoder pi(a_t | s_t, z_t), with the KL term of the beta-weighted objective (Eq. 3).

x_t = [s_t, s_{t+1}, ..., s_{t+K}]: the current state and the next K states of the trajectory to reproduce.
Where fewer than K frames follow (the end of a clip, or a clip shorter than K), the last frame is repeated:
the encoder always sees K + 1 frames, and a one-frame clip is its own target.
Observations are normalised with statistics fixed from the expert data (`fbcpr.nn.normalizer`).
"""
from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from fbcpr.apps.npmp.config import NPMPConfig
from fbcpr.nn.networks import Stack
from fbcpr.nn.normalizer import RunningNormalizer


def prior_params(z_prev: Tensor, alpha: float) -> tuple[Tensor, float]:
    """Mean alpha z_{t-1} and std sqrt(1 - alpha^2) of the AR(1) prior (marginally N(0, I) at every step)."""
    return alpha * z_prev, math.sqrt(1.0 - alpha * alpha)


def kl_to_prior(mean: Tensor, log_std: Tensor, z_prev: Tensor, alpha: float) -> Tensor:
    """KL(q || p) per row, summed over latent dims, for a diagonal Gaussian q and the AR(1) prior at z_prev."""
    p_mean, p_std = prior_params(z_prev, alpha)
    var_ratio = torch.exp(2.0 * log_std) / p_std**2
    return 0.5 * (var_ratio + (mean - p_mean).square() / p_std**2 - 1.0 - torch.log(var_ratio)).sum(-1)


def future_indices(length: int, horizon: int, device: torch.device | None = None) -> Tensor:
    """(length, horizon + 1) frame indices of x_t for t < length: t..t+K, clamped to the last frame."""
    t = torch.arange(length, device=device)[:, None] + torch.arange(horizon + 1, device=device)
    return t.clamp(max=length - 1)


class NPMPModel(nn.Module):
    """Encoder, AR(1) prior and decoder for observations (obs_dim) and actions (action_dim) in [-1, 1]."""

    def __init__(self, cfg: NPMPConfig, obs_dim: int, action_dim: int) -> None:
        super().__init__()
        self.cfg, self.obs_dim, self.action_dim = cfg, obs_dim, action_dim
        d = cfg.latent_dim
        self.obs_normalizer = RunningNormalizer(obs_dim)
        self.encoder = Stack([d + (cfg.horizon + 1) * obs_dim] + [cfg.encoder_hidden] * cfg.encoder_layers + [2 * d],
                             1, final=None)
        self.decoder = Stack([obs_dim + d] + [cfg.decoder_hidden] * cfg.decoder_layers + [action_dim], 1, final=None)

    @property
    def z_dim(self) -> int:
        return self.cfg.latent_dim

    @property
    def device(self) -> torch.device:
        return self.obs_normalizer.mean.device

    def posterior(self, z_prev: Tensor, frames_n: Tensor) -> tuple[Tensor, Tensor]:
        """(mean, log_std) of q(z_t | z_{t-1}, x_t) for normalised frames (N, K+1, obs_dim).

        Parametrised around the prior (mean = alpha z_{t-1} + sigma m, std = sigma exp(l)), so an encoder that
        outputs zeros is the prior and the KL term starts near 0."""
        out = self.encoder(torch.cat([z_prev, frames_n.flatten(1)], -1))[0]
        m, l = out.chunk(2, -1)
        p_mean, p_std = prior_params(z_prev, self.cfg.alpha)
        return p_mean + p_std * m, math.log(p_std) + l.clamp(-10.0, 2.0)

    def decode(self, obs_n: Tensor, z: Tensor) -> Tensor:
        """Mean action tanh(MLP(s, z)) in [-1, 1] at normalised observations (any leading dims)."""
        x = torch.cat([obs_n, z], -1)
        return torch.tanh(self.decoder(x.reshape(-1, x.shape[-1]))[0]).reshape(*x.shape[:-1], self.action_dim)

    @torch.no_grad()
    def encode(self, frames: Tensor) -> Tensor:
        """(T-1, d) latent means z_0..z_{T-2} of a reference (T, obs_dim), one per transition, each from the
        previous one (z_{-1} = 0, the prior's mode): the one-shot latent sequence of the paper's Sec. 3.2."""
        if frames.dim() != 2 or frames.shape[1] != self.obs_dim or frames.shape[0] < 2:
            raise ValueError(f"frames: expected (T >= 2, {self.obs_dim}), got {tuple(frames.shape)}")
        n = self.obs_normalizer(frames.to(self.device, torch.float32))
        windows = n[future_indices(n.shape[0], self.cfg.horizon, n.device)]  # (T, K+1, obs)
        z = torch.zeros(1, self.z_dim, device=n.device)
        out = []
        for t in range(n.shape[0] - 1):  # the AR recursion is sequential in time
            z = self.posterior(z, windows[t:t + 1])[0]
            out.append(z)
        return torch.cat(out)

    @torch.no_grad()
    def act(self, obs: Tensor, z: Tensor) -> Tensor:
        """Decoder mean for raw observations (N, obs_dim) and latents (N, d)."""
        return self.decode(self.obs_normalizer(obs.to(self.device, torch.float32)), z.to(self.device, torch.float32))
