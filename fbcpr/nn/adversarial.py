"""Adversarial imitation maths shared by FB-CPR's discriminator D(s, z) and AMP's D(s, s').

Both discriminators are `fbcpr.nn.networks.Discriminator` (an MLP over the concatenation of two inputs x and c:
(s, z) for FB-CPR, (s, s') for AMP), trained by the same cross-entropy and gradient penalty.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from fbcpr.nn.networks import Discriminator


def discriminator_loss(expert_logits: Tensor, online_logits: Tensor) -> Tensor:
    """Cross-entropy (FB-CPR Algorithm 1 line 15): -mean log D(expert) - mean log(1 - D(online)), from logits."""
    return F.softplus(-expert_logits).mean() + F.softplus(online_logits).mean()


def gradient_penalty(disc: Discriminator, s_expert: Tensor, z_expert: Tensor, s_online: Tensor, z_online: Tensor,
                     mix: Tensor) -> Tensor:
    """WGAN-GP (Gulrajani et al.): mean (||grad_{(s,z)} logit(x_hat)||_2 - 1)^2 on x_hat interpolating both s and z.

    z is the second input: FB-CPR's latent or AMP's s'. mix: (n,) interpolation weights in [0, 1] (the expert
    weight)."""
    w = mix[:, None]
    s = (w * s_expert + (1 - w) * s_online).detach().requires_grad_(True)
    z = (w * z_expert + (1 - w) * z_online).detach().requires_grad_(True)
    logits = disc.logits(s, z)
    gs, gz = torch.autograd.grad(logits.sum(), (s, z), create_graph=True)
    norm = torch.sqrt(gs.square().sum(-1) + gz.square().sum(-1) + 1e-12)
    return (norm - 1.0).square().mean()
