"""Latent optimisation (paper Sec. 3.3, Eq. 10): when one-shot tracking of a clip fails, optimise the latent
sequence directly, min_{z_1..T} sum_t ||mu(s*_t, z_t) - a*_t||^2 along the expert's nominal trajectory, starting
from the encoder's one-shot latents. If the optimised latents track much better, the decoder can express the
behaviour and the encoder is at fault; if not, the decoder is."""
from __future__ import annotations

import torch
from torch import Tensor

from fbcpr.apps.npmp.model import NPMPModel


def optimise_latents(model: NPMPModel, states: Tensor, actions: Tensor, z_init: Tensor, steps: int = 300,
                     lr: float = 0.05) -> tuple[Tensor, float, float]:
    """Optimised (T, d) latents for expert states (T, obs_dim) and actions (T, action_dim), with Adam from z_init;
    returns them with the action MSE before and after. The decoder's weights stay frozen."""
    if not (states.shape[0] == actions.shape[0] == z_init.shape[0]) or states.shape[0] == 0:
        raise ValueError(f"states, actions and z_init need the same T > 0, got {states.shape[0]}, {actions.shape[0]}, "
                         f"{z_init.shape[0]}")
    if steps < 1 or lr <= 0:
        raise ValueError(f"steps must be >= 1 and lr > 0, got {steps} and {lr}")
    obs_n = model.obs_normalizer(states.float()).detach()
    target = actions.float()
    z = z_init.detach().clone().float().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=lr)
    for p in model.parameters():
        p.requires_grad_(False)
    try:
        def mse() -> Tensor:
            return (model.decode(obs_n, z) - target).square().mean()

        before = float(mse().detach())
        for _ in range(steps):
            opt.zero_grad(set_to_none=True)
            loss = mse()
            loss.backward()
            opt.step()
        after = float(mse().detach())
    finally:
        for p in model.parameters():
            p.requires_grad_(True)
    return z.detach(), before, after
