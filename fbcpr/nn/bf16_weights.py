"""bf16 copies of the ensemble layers' weights, refreshed once per step, for a bf16 update with float32 masters.

Under bf16 autocast alone every matmul casts its weight again (a slice of a weight, or a weight detached for the
actor loss, is not in autocast's cache), which on a small update added ~220 cast kernels to ~800. Here the
`EnsembleLinear` weights and biases are copied to bf16 in one foreach copy per step and the layers use the copies
for the step's forward pass (autocast then finds their matmuls' weights in bf16 already and casts only
activations); their gradients, accumulated on the copies, go back to the float32 masters in one more foreach
copy, and the optimiser steps the masters in float32. Layer norms and everything autocast keeps in float32 read
the masters as before.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import torch
from torch import Tensor, nn

from fbcpr.nn.networks import EnsembleLinear


class BF16Weights:
    """The bf16 copies of every `EnsembleLinear` parameter inside `modules` (online networks and target networks
    alike; a master without a gradient gets a copy without one)."""

    def __init__(self, modules: Sequence[nn.Module]) -> None:
        self.slots: list[tuple[nn.Module, str]] = [(layer, name) for module in modules for layer in module.modules()
                                                   if isinstance(layer, EnsembleLinear) for name in ("weight", "bias")]
        self.masters: list[Tensor] = [getattr(layer, name) for layer, name in self.slots]
        self.copies: list[Tensor] = [nn.Parameter(p.detach().to(torch.bfloat16), requires_grad=p.requires_grad)
                       for p in self.masters]
        self.grads: list[Tensor | None] = [torch.zeros_like(p) if p.requires_grad else None for p in self.masters]

    @torch.no_grad()
    def refresh(self) -> None:
        """copies := masters, one foreach copy (after each optimiser step and Polyak average, before a forward)."""
        torch._foreach_copy_(self.copies, self.masters)

    @contextmanager
    def swapped(self) -> Iterator[None]:
        """The layers hold the bf16 copies inside the block (the forward pass), their masters again after it."""
        for (layer, name), copy in zip(self.slots, self.copies):
            copy.grad = None
            setattr(layer, name, copy)
        try:
            yield
        finally:
            for (layer, name), master in zip(self.slots, self.masters):
                setattr(layer, name, master)

    @torch.no_grad()
    def gradients_to_masters(self) -> None:
        """Each master's gradient := its copy's, in float32 (one foreach copy); a master whose copy got none keeps
        none."""
        dst, src = [], []
        for master, copy, buffer in zip(self.masters, self.copies, self.grads):
            if copy.grad is not None and buffer is not None:
                master.grad = buffer
                dst.append(buffer)
                src.append(copy.grad)
                copy.grad = None
        if dst:
            torch._foreach_copy_(dst, src)
