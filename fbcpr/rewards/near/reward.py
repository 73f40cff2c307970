"""NEARReward: the annealed energy of expert (s, s') transitions as an `fbcpr.core.protocols.ImitationReward`.

Pretraining (Algorithm 1's EnergyNCSN) runs once, offline, on the first `fit` call: a dataset M of `dataset_size`
transitions is drawn from the demonstration library the reward was built with, the feature statistics are fixed
from it, and the energy is trained `pretrain_steps` steps of denoising score matching (Adam, gradient clipping,
EMA of the weights; the EMA network is the reward). A checkpoint holds the trained energy, so a resumed run does
not pretrain again. After that `fit` trains nothing: it only anneals, once per rollout phase, on the energies of
the online transitions the agent passed to `observe` (Algorithm 1's annealing buffer A).

Features: x = (s, s' - s), each half standardised by M's statistics (the representation AMPReward uses, for the
same reason: a step moves a state by a small fraction of its spread, which noise on (s, s') would drown), with a
floor on each std (`STD_FLOOR`).
The energy is anchored so that M's mean energy is 0 (DSM learns e only up to a constant, and the annealing rule
divides by energies). Reward: e(x, sigma_k) = e(x) / sigma_k, or with the transform tanh((e(x, sigma_k) - r') /
scale), r' the mean online energy of the last k rollout phases at the current level.
"""
from __future__ import annotations

import copy
import time
from collections import deque
from typing import Any

import numpy as np
import torch
from torch import Tensor

from fbcpr.nn import distributed
from fbcpr.nn.normalizer import RunningNormalizer
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state
from fbcpr.rewards.amp.reward import window_transitions
from fbcpr.rewards.near.annealing import Annealer
from fbcpr.rewards.near.config import NEARConfig
from fbcpr.rewards.near.energy import EnergyNet, dsm_loss, ema_update, noise_levels

#: Each feature's std in M is at least this fraction of its half's median std: a single clip holds features that
#: barely move, and standardising by their ~0 spread would blow any deviation of the agent up by orders of magnitude.
STD_FLOOR = 0.1


def level_reward(energy: Tensor, sigma: float, history: deque[float], cfg: NEARConfig) -> Tensor:
    """The reward of anchored energies at level sigma: e / sigma, or with `cfg.transform` tanh((e / sigma - r') /
    scale), r' the mean of `history` (the last phases' mean online energies) at the same level."""
    r = energy / sigma
    if not cfg.transform:
        return r
    recent = float(np.mean(history)) / sigma if history else 0.0
    return torch.tanh((r - recent) / cfg.transform_scale)


class NEARError(ValueError):
    """NEAR used out of order (no demonstrations to pretrain on) or fed non-finite transitions."""


class NEARReward:
    """Energy network, its EMA copy (the reward), M's feature statistics, the annealer and the transform's history."""

    def __init__(self, obs_dim: int, cfg: NEARConfig, device: str | torch.device = "cpu", seed: int = 0,
                 library: Any = None) -> None:
        self.cfg, self.device, self.library = cfg, torch.device(device), library
        self.normalizer = RunningNormalizer(obs_dim).to(self.device)
        self.step_normalizer = RunningNormalizer(obs_dim).to(self.device)
        self.energy = EnergyNet(2 * obs_dim, cfg.hidden_dim, cfg.hidden_layers).to(self.device)
        self.ema = copy.deepcopy(self.energy).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.energy.parameters(), lr=cfg.lr)
        self.sigmas = noise_levels(cfg.sigma_max, cfg.sigma_min, cfg.num_levels).to(self.device)
        self.annealer = Annealer(cfg.num_levels, cfg.anneal_threshold)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed + 2)  # not the agent's stream, nor AMP's
        self.rng = np.random.default_rng(seed + 2)  # draws M from the library
        self.pretrained = False
        self.pretrain_stats: dict[str, float] = {}  # DSM loss at the start and end of pretraining, its wall time
        self.anchor = 0.0
        self.phase_energies: deque[float] = deque(maxlen=cfg.transform_history)
        self._phase = torch.zeros(2, dtype=torch.float64, device=self.device)  # sum and count of A's energies
        self._progress = 0.0

    # ------------------------------------------------------------------------------------- energy
    def features(self, obs: Tensor, next_obs: Tensor) -> Tensor:
        """x = (s, s' - s) standardised by M's statistics, (n, 2 * obs_dim)."""
        if not (torch.isfinite(obs).all() and torch.isfinite(next_obs).all()):
            raise NEARError("NEAR: non-finite values in the (obs, next_obs) transitions")
        return torch.cat([self.normalizer(obs), self.step_normalizer(next_obs - obs)], -1)

    @torch.no_grad()
    def anchored_energy(self, obs: Tensor, next_obs: Tensor) -> Tensor:
        """e(x) - mean e(M) of the EMA network for raw transitions, (n,): the unconditional energy, 0 on the data."""
        return self.ema(self.features(obs.to(self.device, torch.float32), next_obs.to(self.device, torch.float32))) \
            - self.anchor

    @property
    def sigma(self) -> float:
        """The current level's noise scale sigma_k."""
        return float(self.sigmas[self.annealer.level])

    # ------------------------------------------------------------------------------------- pretraining
    def pretrain(self, pairs: Tensor | None = None) -> dict[str, float]:
        """Algorithm 1's EnergyNCSN on M: `pairs` (n, 2, obs_dim) of (s, s'), or `dataset_size` drawn from the
        library. Returns the DSM loss at the start and end and the wall time."""
        cfg, dev = self.cfg, self.device
        if pairs is None:
            if self.library is None:
                raise NEARError("NEAR: no demonstration library to pretrain the energy on (pass library= or pairs)")
            pairs = torch.as_tensor(self.library.sample_windows(self.rng, cfg.dataset_size, 2))
        s, s_next = window_transitions(pairs.to(dev, torch.float32))
        for norm, x in ((self.normalizer, s), (self.step_normalizer, s_next - s)):
            norm.count.zero_()
            norm.update(x)
            norm.var.clamp_(min=float(norm.var.sqrt().median() * STD_FLOOR) ** 2)
        data = self.features(s, s_next)
        t0, losses = time.perf_counter(), []
        for _ in range(cfg.pretrain_steps):
            idx = torch.randint(len(data), (cfg.batch_size,), generator=self.generator, device=dev)
            loss = dsm_loss(self.energy, data[idx], self.sigmas, self.generator)
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.energy.parameters(), cfg.grad_clip)
            self.optimizer.step()
            ema_update(self.ema, self.energy, cfg.ema)
            losses.append(loss.detach())
        with torch.no_grad():
            self.anchor = float(self.ema(data).mean())
        self.pretrained = True
        curve = torch.stack(losses).tolist()
        k = max(1, len(curve) // 10)
        self.pretrain_stats = {"near/dsm_first": float(np.mean(curve[:k])), "near/dsm_last": float(np.mean(curve[-k:])),
                               "near/pretrain_s": time.perf_counter() - t0}
        return self.pretrain_stats

    # ------------------------------------------------------------------------------------- ImitationReward
    def observe(self, obs: Tensor, next_obs: Tensor) -> None:
        """Online transitions as the agent collects them: Algorithm 1's annealing buffer A (kept as a sum)."""
        if self.pretrained:
            e = self.anchored_energy(obs, next_obs).to(torch.float64)
            self._phase += torch.stack([e.sum(), torch.tensor(float(len(e)), dtype=torch.float64, device=e.device)])

    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """Pretrain on the first call; afterwards anneal once per rollout phase (when A holds transitions).
        NEAR's energy learns nothing from the agent, so the windows and batch are not used. The metrics repeat
        the pretraining figures, so every logged row has them."""
        if not self.pretrained:
            self.pretrain()
        replicas = distributed.active()  # under torchrun every rank anneals on all ranks' transitions, in step
        phase = self._phase.cpu().numpy() if replicas is None else replicas.sum(self._phase.cpu().numpy())
        total, count = phase.tolist()
        if count > 0:
            mean = total / count
            self.phase_energies.append(mean)
            if self.cfg.anneal:
                self._progress = self.annealer.step(mean / self.sigma)
            self._phase.zero_()
        return {**self.pretrain_stats, "near/level": float(self.annealer.level), "near/sigma": self.sigma,
                "near/progress": self._progress,
                "near/energy_online": self.phase_energies[-1] if self.phase_energies else 0.0}

    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> Tensor:
        """e(s, s', sigma_k), or its tanh transform, for raw transitions, (n,); z is not used."""
        if not self.pretrained:
            raise NEARError("NEAR: the energy is not trained yet (fit or pretrain first)")
        return level_reward(self.anchored_energy(obs, next_obs), self.sigma, self.phase_energies, self.cfg)

    # ------------------------------------------------------------------------------------- state
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        tensors: dict[str, Tensor] = {}
        for name, module in self._modules().items():
            tensors.update({f"{name}.{k}": v for k, v in module.state_dict().items()})
        meta = {"optimizer": optimizer_state(self.optimizer, "optim", tensors), "pretrained": self.pretrained,
                "pretrain_stats": self.pretrain_stats,
                "anchor": self.anchor, "annealer": self.annealer.state(), "history": list(self.phase_energies),
                "phase": self._phase.tolist(), "progress": self._progress, "rng": self.rng.bit_generator.state}
        tensors["generator"] = self.generator.get_state()
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        from fbcpr.core.checkpoint import load_state_strict

        for name, module in self._modules().items():
            part = {k[len(name) + 1:]: v for k, v in tensors.items() if k.startswith(f"{name}.")}
            load_state_strict(module, part, f"trainer_state.safetensors (NEAR {name})")
        load_optimizer_state(self.optimizer, "optim", meta["optimizer"], tensors)
        self.generator.set_state(tensors["generator"])
        self.pretrained, self.anchor, self._progress = bool(meta["pretrained"]), float(meta["anchor"]), meta["progress"]
        self.pretrain_stats = dict(meta["pretrain_stats"])
        self.annealer.load_state(meta["annealer"])
        self.phase_energies = deque(meta["history"], maxlen=self.cfg.transform_history)
        self._phase = torch.tensor(meta["phase"], dtype=torch.float64, device=self.device)
        self.rng.bit_generator.state = meta["rng"]

    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"energy": self.energy, "ema": self.ema, "normalizer": self.normalizer,
                "step_normalizer": self.step_normalizer}
