"""NEAR as FB-CPR's conditional policy regulariser (`agent.regulariser: near`; beyond both papers).

FB-CPR trains its critic Q(s, a, z) on the discriminator's log-ratio log D(s, z) - log(1 - D(s, z)). With this
option the critic is trained on a z-conditioned energy instead, e(x, z, sigma) = e(x, z) / sigma over transitions
x = (s, s' - s), learned by denoising score matching on expert transitions conditioned on the ER_FB latent of
their window: the (expert, z) pairing of the discriminator's expert pairs. The energy never sees the agent's
transitions, so the reward is not adversarial.

Unlike `NEARReward`, the energy trains online, one DSM step per FB-CPR update inside the agent's one backward
pass (its own Adam optimiser, gradient clipping, an EMA copy that gives the reward): the latents it is conditioned
on are B's, and B keeps learning, so an energy pretrained offline would be conditioned on stale latents.

- Features: s normalised by the model's observation normaliser (what every FB-CPR network sees), s' - s by a
  `RunningNormalizer` of the expert steps, with NEAR's std floor (`STD_FLOOR`) applied when it is used.
- Anchor: DSM fixes e only up to a constant, and an online-trained energy drifts; each update's reward subtracts
  the EMA energy's mean over that update's expert transitions, so expert-like transitions score ~0.
- Annealing (Algorithm 1) on the transitions each rollout phase collected, with the latent each was collected under
  (the buffer A, passed by the trainer through `FBCPRAgent.observe`). At the first update after the phase, before
  any weight moves, the energy that scored A also scores the update's expert windows, and the rule of `Annealer`
  is applied to the gap g = mean e(A) - mean e(expert), divided by sigma_k: the agent's distance to the expert
  under one network, so the energy's own drift between phases does not read as progress.
"""
from __future__ import annotations

import copy
from collections import deque
from typing import Any

import torch
from torch import Tensor, nn

from fbcpr.nn import distributed
from fbcpr.nn.normalizer import RunningNormalizer
from fbcpr.rewards.near.annealing import Annealer
from fbcpr.rewards.near.config import NEARConfig
from fbcpr.rewards.near.energy import EnergyNet, dsm_loss, ema_update, noise_levels
from fbcpr.rewards.near.reward import STD_FLOOR, level_reward


class ConditionalEnergy(nn.Module):
    """e(x, z) with its EMA copy and step normaliser (the state dict), the sigma ladder, the annealer and the
    transform's history. obs_n arguments are normalised by the FB-CPR model; steps are raw s' - s."""

    sigmas: Tensor
    _phase: Tensor

    def __init__(self, obs_dim: int, z_dim: int, cfg: NEARConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.step_normalizer = RunningNormalizer(obs_dim)
        self.energy = EnergyNet(2 * obs_dim, cfg.hidden_dim, cfg.hidden_layers, cond_dim=z_dim)
        self.ema = copy.deepcopy(self.energy).requires_grad_(False)
        self.register_buffer("sigmas", noise_levels(cfg.sigma_max, cfg.sigma_min, cfg.num_levels), persistent=False)
        self.register_buffer("_phase", torch.zeros(2, dtype=torch.float64), persistent=False)  # sum, count of e(A)
        self.annealer = Annealer(cfg.num_levels, cfg.anneal_threshold)
        self.history: deque[float] = deque(maxlen=cfg.transform_history)  # the last phases' gaps g
        self.progress = 0.0

    @property
    def sigma(self) -> float:
        """The current level's noise scale sigma_k."""
        return float(self.sigmas[self.annealer.level])

    def features(self, obs_n: Tensor, step: Tensor) -> Tensor:
        """x = (s normalised, s' - s standardised by the expert steps' statistics with a floored std), (n, 2 obs)."""
        norm = self.step_normalizer
        std = torch.sqrt(norm.var + norm.eps)
        std = torch.maximum(std, std.median() * STD_FLOOR)
        return torch.cat([obs_n, ((step - norm.mean) / std).to(obs_n.dtype)], -1)

    def expert_terms(self, expert_n: Tensor, expert: Tensor, z_exp: Tensor,
                     generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """(DSM loss, anchor) on the transitions of expert windows, normalised (w, L, obs) and raw, each conditioned
        on its window's latent z_exp (w, d); the anchor is the EMA energy's mean over them (no gradient)."""
        w, L, o = expert.shape
        x = self.features(expert_n[:, :-1].reshape(-1, o), (expert[:, 1:] - expert[:, :-1]).reshape(-1, o))
        z = z_exp.repeat_interleave(L - 1, 0)
        loss = dsm_loss(self.energy, x, self.sigmas, generator, z)
        with torch.no_grad():
            anchor = self.ema(x, z).mean()
        return loss, anchor

    @torch.no_grad()
    def reward(self, obs_n: Tensor, step: Tensor, z: Tensor, anchor: Tensor) -> Tensor:
        """The critic's reward at the current level: `level_reward` of the anchored EMA energy, (n,)."""
        return level_reward(self.ema(self.features(obs_n, step), z) - anchor, self.sigma, self.history, self.cfg)

    @torch.no_grad()
    def observe(self, obs_n: Tensor, step: Tensor, z: Tensor) -> None:
        """Online transitions as collected, with their rollout latents: the annealing buffer A (a sum)."""
        e = self.ema(self.features(obs_n, step), z).to(torch.float64)
        self._phase += torch.stack([e.sum(), e.new_tensor(float(len(e)))])

    def end_phase(self, anchor: float) -> dict[str, float]:
        """At the first update after a rollout phase (A holds transitions): the gap g to this update's expert
        energy `anchor`, then one annealing step on g / sigma_k (under torchrun on every rank's A and anchor)."""
        if float(self._phase[1]) > 0:
            stats = torch.cat([self._phase.cpu(), torch.tensor([anchor, 1.0], dtype=torch.float64)]).numpy()
            replicas = distributed.active()
            total, count, anchors, ranks = (stats if replicas is None else replicas.sum(stats)).tolist()
            gap = total / count - anchors / ranks
            self.history.append(gap)
            if self.cfg.anneal:
                self.progress = self.annealer.step(gap / self.sigma)
            self._phase.zero_()
        return {"near/level": float(self.annealer.level), "near/sigma": self.sigma, "near/progress": self.progress,
                "near/gap": self.history[-1] if self.history else 0.0}

    def step_ema(self) -> None:
        """The EMA copy follows the weights after each optimiser step."""
        ema_update(self.ema, self.energy, self.cfg.ema)

    def meta(self) -> dict[str, Any]:
        """JSON state beyond the state dict: annealing level and reference, history, the open phase's sums."""
        return {"annealer": self.annealer.state(), "history": list(self.history), "phase": self._phase.tolist(),
                "progress": self.progress}

    def load_meta(self, meta: dict[str, Any]) -> None:
        self.annealer.load_state(meta["annealer"])
        self.history = deque(meta["history"], maxlen=self.cfg.transform_history)
        self._phase.copy_(torch.tensor(meta["phase"], dtype=torch.float64))
        self.progress = float(meta["progress"])
