"""The losses of Algorithm 1 (App. B) as pure functions of network outputs, so each can be checked by hand.

Shapes: m = ensemble size, n = batch size, d = z dimension. `discount` is the per-sample gamma * (1 - terminated).
The ensemble TD loss and reduction (`fbcpr.nn.ensemble_td`) and the discriminator's loss and gradient penalty
(`fbcpr.nn.adversarial`) are shared with the other methods and re-exported here under Algorithm 1's names.
Ensemble-valued losses return the sum over members: each member's parameters only receive the gradient
of its own term, and B receives the sum over members, as in lines 35-36 of Algorithm 1.
"""
from __future__ import annotations

import torch
from torch import Tensor

from fbcpr.nn.adversarial import discriminator_loss, gradient_penalty  # noqa: F401  (Algorithm 1 lines 15-16)
from fbcpr.nn.ensemble_td import action_penalty, pessimistic, td_loss  # noqa: F401  (lines 25, 29, 32)


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
        # no error check and two triangular solves: a checked factorisation, or a solver that reads its status on
        # the host, would wait for the device, which a captured update cannot (fbcpr.nn.cuda_graph)
        chol = torch.linalg.cholesky_ex(cov).L
        solved = torch.linalg.solve_triangular(chol.mT, torch.linalg.solve_triangular(chol, z.T, upper=False),
                                               upper=True)
        return (B_next * solved.T).sum(-1)


def actor_loss(Fz: Tensor, Q: Tensor, alpha: float, coef: float, action: Tensor | None = None,
               action_coef: float = 0.0, anchor_gap: Tensor | None = None, anchor_coef: float = 0.0) -> Tensor:
    """Line 32: -mean(Fz_pess + alpha * stopgrad(mean |Fz_pess|) * Q_pess). Fz, Q: (m, n) at policy actions.

    action_coef > 0 adds `action_penalty` on the policy's actions (n, a), and anchor_coef > 0 adds
    anchor_coef * anchor_gap (`fbcpr.methods.fb_cpr.anchor`), both scaled by the same mean |Fz_pess|."""
    fz = pessimistic(Fz, coef)
    q = pessimistic(Q, coef)
    scale = fz.abs().mean().detach()
    loss = -(fz + alpha * scale * q).mean()
    if action is not None and action_coef > 0.0:
        loss = loss + action_penalty(action, scale, action_coef)
    if anchor_gap is not None and anchor_coef > 0.0:
        loss = loss + anchor_coef * scale * anchor_gap
    return loss
