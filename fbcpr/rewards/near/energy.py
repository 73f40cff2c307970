"""The energy network and its denoising-score-matching loss over a geometric noise ladder (NEAR Sec. 4.1, Eq. 2).

Sign convention: higher energy = closer to the data, so e approximates log q_sigma up to a constant and its input
gradient is the score. Noise conditioning is e(x, sigma) = e(x) / sigma (Song & Ermon 2020, the paper's choice).
The loss is Eq. 2 with NCSN's sigma^2 weighting of each level, which makes every level's term O(1):
    1/2 E || sigma * grad_x' e(x', sigma) + (x' - x) / sigma ||^2,   x' = x + sigma * eps.
"""
from __future__ import annotations

import torch
from torch import Tensor, nn


def noise_levels(sigma_max: float, sigma_min: float, num_levels: int) -> Tensor:
    """sigma_1 = sigma_max > ... > sigma_L = sigma_min, geometric (float32, (L,))."""
    return torch.logspace(torch.log10(torch.tensor(sigma_max)), torch.log10(torch.tensor(sigma_min)), num_levels)


class EnergyNet(nn.Module):
    """Energy e(x), or e(x, c) with a condition c (FB-CPR's latent z) concatenated to x: an ELU MLP (smooth, so the
    score and its parameter gradient are too) with Xavier uniform weights, as the paper's NCSN (App. B.2.1; a plain
    MLP here instead of its auto-encoder shape). Only x is noised and differentiated; c is an input."""

    def __init__(self, in_dim: int, hidden: int, hidden_layers: int, cond_dim: int = 0) -> None:
        super().__init__()
        sizes = [in_dim + cond_dim] + [hidden] * hidden_layers
        layers: list[nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:]):
            layers += [nn.Linear(a, b), nn.ELU()]
        self.net = nn.Sequential(*layers, nn.Linear(sizes[-1], 1))
        for m in self.net:
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, x: Tensor, cond: Tensor | None = None) -> Tensor:
        """(n, in_dim) [and (n, cond_dim)] -> (n,)."""
        return self.net(x if cond is None else torch.cat([x, cond.to(x.dtype)], -1))[:, 0]


def dsm_loss(energy: EnergyNet, x: Tensor, sigmas: Tensor, generator: torch.Generator,
             cond: Tensor | None = None) -> Tensor:
    """Eq. 2 on a batch of (normalised) data x, one noise level drawn uniformly per sample; `cond` (n, c) conditions
    each sample's energy (the score is taken in x only)."""
    n = x.shape[0]
    idx = torch.randint(len(sigmas), (n,), generator=generator, device=x.device)
    sigma = sigmas.to(x.device)[idx][:, None]
    eps = torch.randn(x.shape, generator=generator, device=x.device)
    noisy = (x + sigma * eps).requires_grad_(True)
    e = (energy(noisy) if cond is None else energy(noisy, cond)) / sigma[:, 0]
    score, = torch.autograd.grad(e.sum(), noisy, create_graph=True)
    return 0.5 * (sigma * score + eps).square().sum(-1).mean()


@torch.no_grad()
def ema_update(ema: nn.Module, net: nn.Module, decay: float) -> None:
    """ema <- decay * ema + (1 - decay) * net, one fused op (a function of the weights only, so replicas agree)."""
    torch._foreach_lerp_(list(ema.parameters()), list(net.parameters()), 1.0 - decay)
