"""AMPReward: an AMP/GAIfO-style discriminator D(s, s') on state transitions, as an `ImitationReward`.

Expert transitions are the consecutive pairs of demonstration windows (one clip or many: the env's library);
online transitions are the agent's replay batch. Fitting is one step of the cross-entropy with the WGAN gradient
penalty on interpolated (s, s') (`fbcpr.nn.adversarial`, the same maths as FB-CPR's D(s, z)), against the agent as it
learns. The reward is the logit log D - log(1 - D), as FB-CPR's.

D sees a transition as (s, s' - s), the same information as (s, s'), each part normalised by its own running
statistics over both sources: one step moves a state by a fraction of its spread, so in (s, s') the difference
that separates expert from agent (how it moves) is a small one between two large inputs, which the gradient
penalty keeps D from resolving (on the toy, policies then learned to stand still).
"""
from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from fbcpr.nn.adversarial import discriminator_loss, gradient_penalty
from fbcpr.nn.networks import Discriminator
from fbcpr.nn.normalizer import RunningNormalizer
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state
from fbcpr.rewards.amp.config import AMPConfig


def window_transitions(windows: Tensor) -> tuple[Tensor, Tensor]:
    """All consecutive (s, s') pairs of (w, L, obs_dim) windows: two (w * (L - 1), obs_dim) tensors."""
    o = windows.shape[-1]
    return windows[:, :-1].reshape(-1, o), windows[:, 1:].reshape(-1, o)


class AMPReward:
    """D(s, s') with its normaliser, Adam optimiser and random stream."""

    def __init__(self, obs_dim: int, cfg: AMPConfig, device: str | torch.device = "cpu", seed: int = 0,
                 library: Any = None) -> None:
        """`library` is not kept: AMP learns online from the expert windows each `fit` receives."""
        self.cfg, self.device = cfg, torch.device(device)
        self.normalizer = RunningNormalizer(obs_dim).to(self.device)
        self.step_normalizer = RunningNormalizer(obs_dim).to(self.device)
        self.discriminator = Discriminator(obs_dim, obs_dim, cfg.hidden_dim, cfg.hidden_layers).to(self.device)
        self.optimizer = torch.optim.Adam(self.discriminator.parameters(), lr=cfg.lr)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed + 1)  # not the agent's stream

    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """One discriminator step: expert pairs of the windows vs the batch's (obs, next_obs)."""
        dev = self.device
        s_e, n_e = window_transitions(expert_windows.to(dev, torch.float32))
        s_o, n_o = (batch[k].to(dev, torch.float32) for k in ("obs", "next_obs"))
        self.normalizer.update(torch.cat([s_e, s_o]))
        self.step_normalizer.update(torch.cat([n_e - s_e, n_o - s_o]))
        (s_e, n_e), (s_o, n_o) = self._inputs(s_e, n_e), self._inputs(s_o, n_o)
        ne = s_e.shape[0]
        logits = self.discriminator.logits(torch.cat([s_e, s_o]), torch.cat([n_e, n_o]))
        disc = discriminator_loss(logits[:ne], logits[ne:])
        k = min(ne, s_o.shape[0])
        mix = torch.rand(k, generator=self.generator, device=dev)
        gp = gradient_penalty(self.discriminator, s_e[:k], n_e[:k], s_o[:k], n_o[:k], mix)
        self.optimizer.zero_grad(set_to_none=True)
        (disc + self.cfg.grad_penalty * gp).backward()
        self.optimizer.step()
        values = torch.stack([disc.detach(), gp.detach(), torch.sigmoid(logits[:ne]).mean().detach(),
                              torch.sigmoid(logits[ne:]).mean().detach()]).tolist()
        return dict(zip(("amp/disc_loss", "amp/grad_penalty", "amp/disc_expert", "amp/disc_online"), values))

    def _inputs(self, obs: Tensor, next_obs: Tensor) -> tuple[Tensor, Tensor]:
        """D's two inputs for raw transitions: normalised s and normalised s' - s."""
        return self.normalizer(obs), self.step_normalizer(next_obs - obs)

    @torch.no_grad()
    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> Tensor:
        """log D - log(1 - D) of raw transitions (s, s'); z is not used (the reward is not latent-conditioned)."""
        return self.discriminator.logits(*self._inputs(obs.to(self.device), next_obs.to(self.device)))

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        tensors = {f"discriminator.{k}": v for k, v in self.discriminator.state_dict().items()}
        tensors.update({f"normalizer.{k}": v for k, v in self.normalizer.state_dict().items()})
        tensors.update({f"step_normalizer.{k}": v for k, v in self.step_normalizer.state_dict().items()})
        meta = {"optimizer": optimizer_state(self.optimizer, "optim", tensors)}
        tensors["generator"] = self.generator.get_state()
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        from fbcpr.core.checkpoint import load_state_strict

        for name, module in (("discriminator", self.discriminator), ("normalizer", self.normalizer),
                             ("step_normalizer", self.step_normalizer)):
            part = {k[len(name) + 1:]: v for k, v in tensors.items() if k.startswith(f"{name}.")}
            load_state_strict(module, part, f"trainer_state.safetensors (AMP {name})")
        load_optimizer_state(self.optimizer, "optim", meta["optimizer"], tensors)
        self.generator.set_state(tensors["generator"])
