"""The losses of Algorithm 1 (App. B) as pure functions of network outputs, so each can be checked by hand.

Shapes: m = ensemble size, n = batch size, d = z dimension. `discount` is the per-sample gamma * (1 - terminated).
Ensemble-valued losses return the sum over members: each member's parameters only receive the gradient
of its own term, and B receives the sum over members, as in lines 35-36 of Algorithm 1.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from fbcpr.networks import Discriminator


def pessimistic(values: Tensor, coef: float) -> Tensor:
    """Ensemble reduction of C.5.2: mean minus coef * mean pairwise |difference| over dim 0.

    coef = 0 gives the mean; for two members coef = 0.5 gives their minimum.
    """
    m = values.shape[0]
    mean = values.mean(0)
    if coef == 0.0 or m == 1:
        return mean
    spread = (values.unsqueeze(0) - values.unsqueeze(1)).abs().sum((0, 1)) / (m * (m - 1))
    return mean - coef * spread


def _off_diagonal_mean_sq(x: Tensor) -> Tensor:
    """sum_{i != j} x_ij^2 / (2 n (n-1)) over the last two dims, summed over leading dims."""
    n = x.shape[-1]
    off = x.square().sum((-2, -1)) - torch.diagonal(x, dim1=-2, dim2=-1).square().sum(-1)
    return (off / (2 * n * (n - 1))).sum()


def fb_loss(M: Tensor, target_M: Tensor, discount: Tensor) -> Tensor:
    """FB TD loss (line 21). M: (m, n, n) with M_k[i, j] = F_k(s_i, a_i, z_i)^T B(s'_j);
    target_M: (n, n) = ensemble-reduced target F(s'_i, a'_i, z_i)^T target B(s'_j)."""
    diff = M - discount[:, None] * target_M
    diag = torch.diagonal(M, dim1=-2, dim2=-1).mean(-1).sum()
    return _off_diagonal_mean_sq(diff) - diag


def ortho_loss(B: Tensor) -> Tensor:
    """Orthonormality regulariser (line 23): pushes E[B(s) B(s)^T] toward the identity. B: (n, d)."""
    cov = B @ B.T
    return _off_diagonal_mean_sq(cov) - torch.diagonal(cov).mean()


def implicit_reward(B_next: Tensor, z: Tensor, ridge: float = 1e-6) -> Tensor:
    """B(s')^T Sigma_B^{-1} z with Sigma_B = E[B B^T] over the batch (line 25), without gradient.

    Solved by Cholesky with a ridge of `ridge` x mean eigenvalue (keeps batches with n < d finite); an
    eigendecomposition-based pseudo-inverse costs more than a whole network forward here."""
    with torch.no_grad(), torch.autocast(B_next.device.type, enabled=False):
        B_next, z = B_next.float(), z.float()
        d = B_next.shape[1]
        cov = B_next.T @ B_next / B_next.shape[0]
        cov = cov + ridge * cov.diagonal().mean() * torch.eye(d, dtype=cov.dtype, device=cov.device)
        chol = torch.linalg.cholesky(cov)
        return (B_next * torch.cholesky_solve(z.T, chol).T).sum(-1)


def td_loss(values: Tensor, reward: Tensor, target: Tensor, discount: Tensor) -> Tensor:
    """Sum over members of mean_i (v_k,i - r_i - discount_i * target_i)^2 (lines 25 and 29). values: (m, n)."""
    return (values - (reward + discount * target)).square().mean(-1).sum()


def discriminator_loss(expert_logits: Tensor, online_logits: Tensor) -> Tensor:
    """Cross-entropy (line 15): -mean log D(expert) - mean log(1 - D(online)), from logits."""
    return F.softplus(-expert_logits).mean() + F.softplus(online_logits).mean()


def gradient_penalty(disc: Discriminator, s_expert: Tensor, z_expert: Tensor, s_online: Tensor, z_online: Tensor,
                     mix: Tensor) -> Tensor:
    """WGAN-GP (Gulrajani et al.): mean (||grad_{(s,z)} logit(x_hat)||_2 - 1)^2 on x_hat interpolating both s and z.

    mix: (n,) interpolation weights in [0, 1] (the expert weight)."""
    w = mix[:, None]
    s = (w * s_expert + (1 - w) * s_online).detach().requires_grad_(True)
    z = (w * z_expert + (1 - w) * z_online).detach().requires_grad_(True)
    logits = disc.logits(s, z)
    gs, gz = torch.autograd.grad(logits.sum(), (s, z), create_graph=True)
    norm = torch.sqrt(gs.square().sum(-1) + gz.square().sum(-1) + 1e-12)
    return (norm - 1.0).square().mean()


def actor_loss(Fz: Tensor, Q: Tensor, alpha: float, coef: float) -> Tensor:
    """Line 32: -mean(Fz_pess + alpha * stopgrad(mean |Fz_pess|) * Q_pess). Fz, Q: (m, n) at policy actions."""
    fz = pessimistic(Fz, coef)
    q = pessimistic(Q, coef)
    scale = fz.abs().mean().detach()
    return -(fz + alpha * scale * q).mean()
