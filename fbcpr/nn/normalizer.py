"""Running observation normalizer (App. C.5.1: running mean/std of the states in each update's batches).

Statistics are kept in float64 buffers and merged batch by batch (Chan et al.'s parallel update), so they
are exact whatever the batch sizes; they live in the model's state dict and are saved with it. Under data-parallel
training (`fbcpr.nn.distributed`) a batch's moments are first merged over the ranks' batches, so every rank folds in the
statistics of the global batch and all normalise alike.
"""
from __future__ import annotations

import torch
from torch import Tensor, nn

from fbcpr.nn import distributed


class RunningNormalizer(nn.Module):
    """x -> (x - mean) / sqrt(var + eps); identity until the first `update`."""

    mean: Tensor
    var: Tensor
    count: Tensor

    def __init__(self, dim: int, eps: float = 1e-5, enabled: bool = True) -> None:
        super().__init__()
        self.eps, self.enabled = eps, enabled
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        """Merge the statistics of a batch (n, dim) (of every rank's batch inside `Replicas.synchronized()`)."""
        if not self.enabled:
            return
        x = x.detach().to(torch.float64).reshape(-1, self.mean.shape[0])
        n = float(x.shape[0])
        b_mean = x.mean(0) if n else torch.zeros_like(self.mean)
        b_var = x.var(0, unbiased=False) if n else torch.zeros_like(self.var)
        replicas = distributed.active()
        if replicas is not None:
            n, b_mean, b_var = replicas.merge_moments(n, b_mean, b_var)
        if n == 0:
            return
        total = self.count + n
        delta = b_mean - self.mean
        m2 = self.var * self.count + b_var * n + delta.square() * self.count * n / total
        self.mean.add_(delta * n / total)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def forward(self, x: Tensor) -> Tensor:
        if not self.enabled:
            return x
        mean = self.mean.to(x.dtype)
        std = torch.sqrt(self.var + self.eps).to(x.dtype)
        return (x - mean) / std
