"""FB-CPR's discriminator D(s, z) as an `fbcpr.core.protocols.ImitationReward`, and the terms that train it.

Expert pairs are (s, ER_FB(window)) for the states of demonstration windows, online pairs (s, z) from the replay
buffer (line 15 of Algorithm 1); the reward is the logit log D - log(1 - D) (line 27). `FBCPRAgent` computes
`discriminator_terms` inside its one fused update; `DiscriminatorReward` trains the same discriminator on its
own, so the latent-conditioned reward can drive another learner or be inspected outside training.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.nn.adversarial import discriminator_loss, gradient_penalty
from fbcpr.nn.networks import Discriminator, project_sphere
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state


@torch.no_grad()
def encode_windows(model: FBCPRModel, windows_n: Tensor) -> Tensor:
    """ER_FB: mean of B over each (normalized) window, projected to the sphere. (w, L, obs) -> (w, d)."""
    w, L, o = windows_n.shape
    return project_sphere(model.backward_map(windows_n.reshape(w * L, o)).view(w, L, -1).mean(1))


def penalty_pairs(expert_n: Tensor, obs_n: Tensor) -> int:
    """How many (expert, online) pairs the gradient penalty interpolates: one weight each is drawn for them."""
    return min(expert_n.shape[0] * expert_n.shape[1], obs_n.shape[0])


def discriminator_terms(disc: Discriminator, expert_n: Tensor, z_exp: Tensor, obs_n: Tensor, z: Tensor,
                        mix: Tensor, penalty: Callable[..., Tensor] = gradient_penalty
                        ) -> tuple[Tensor, Tensor, Tensor]:
    """(logits, cross-entropy, gradient penalty): expert (s, ER_FB) of windows (w, L, obs) with their latents z_exp
    (w, d) vs online (s, z), in one forward; the first w * L logits are the expert's. mix: the penalty's
    `penalty_pairs` interpolation weights, uniform in [0, 1]."""
    w, L, o = expert_n.shape
    z_exp_states = z_exp.repeat_interleave(L, 0)
    s_exp = expert_n.reshape(w * L, o)
    logits = disc.logits(torch.cat([s_exp, obs_n]), torch.cat([z_exp_states, z]))
    loss = discriminator_loss(logits[: w * L], logits[w * L:])
    k = mix.shape[0]
    return logits, loss, penalty(disc, s_exp[:k], z_exp_states[:k], obs_n[:k], z[:k], mix)


class DiscriminatorReward:
    """The discriminator of an `FBCPRModel` with an optimiser of its own (the model's B and normaliser are read)."""

    def __init__(self, model: FBCPRModel, lr: float = 1e-5, grad_penalty: float = 10.0, seed: int = 0) -> None:
        self.model, self.grad_penalty = model, grad_penalty
        self.optimizer = torch.optim.Adam(model.discriminator.parameters(), lr=lr)
        self.generator = torch.Generator(device=model.device)
        self.generator.manual_seed(seed)

    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """One step on raw expert windows (w, L, obs_dim) vs the batch's (obs, z)."""
        model, dev = self.model, self.model.device
        expert_n = model.normalize(expert_windows.to(dev, torch.float32))
        obs_n, z = model.normalize(batch["obs"].to(dev, torch.float32)), batch["z"].to(dev, torch.float32)
        mix = torch.rand(penalty_pairs(expert_n, obs_n), generator=self.generator, device=dev)
        logits, loss, gp = discriminator_terms(model.discriminator, expert_n, encode_windows(model, expert_n), obs_n,
                                               z, mix)
        self.optimizer.zero_grad(set_to_none=True)
        (loss + self.grad_penalty * gp).backward()
        self.optimizer.step()
        ne = expert_n.shape[0] * expert_n.shape[1]
        values = torch.stack([loss.detach(), gp.detach(), torch.sigmoid(logits[:ne]).mean().detach(),
                              torch.sigmoid(logits[ne:]).mean().detach()]).tolist()
        return dict(zip(("disc_loss", "grad_penalty", "disc_expert", "disc_online"), values))

    @torch.no_grad()
    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> Tensor:
        """log D(s, z) - log(1 - D(s, z)) for raw states s (FB-CPR scores the state, not the transition)."""
        if z is None:
            raise ValueError("DiscriminatorReward.reward: FB-CPR's discriminator needs the latent z of each state")
        return self.model.discriminator.logits(self.model.normalize(obs.to(self.model.device)), z.to(self.model.device))

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """Optimiser and random stream (the discriminator's weights are part of the model's checkpoint)."""
        tensors: dict[str, Tensor] = {}
        meta = {"optimizer": optimizer_state(self.optimizer, "optim", tensors)}
        tensors["generator"] = self.generator.get_state()
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        load_optimizer_state(self.optimizer, "optim", meta["optimizer"], tensors)
        self.generator.set_state(tensors["generator"])
