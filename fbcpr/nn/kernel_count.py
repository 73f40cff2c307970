"""How many kernels one update launches, counted on any device (the CPU included).

On a GPU a small update is launch-bound: its time is set by the number of kernels, not by their math
(docs/benchmarks.md). The count is the number of aten operators that reach the dispatcher's Python mode
(`TorchDispatchMode`) while one update runs: the forward pass, every operator that autograd's backward runs,
and the optimisers' steps and Polyak averaging. Composite operators arrive there already decomposed (so
`F.linear` counts as the ops it becomes, as it would launch), a `_foreach_*` or fused-optimiser operator counts
once however many tensors it covers, and an operator that a compiled region fused into its own code does not
reach the dispatcher at all (it is one kernel with the region's other pointwise work, which is not counted).
Views and other metadata-only operators (`view`, `expand`, `t`, `detach`, `as_strided`, ...: `OpOverload.is_view`)
launch nothing on a GPU and are kept apart, as are the profiler's record-function markers: `kernels` leaves them out,
`total` has them. `.item()` (`_local_scalar_dense`, a copy to the host) counts as a kernel.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from torch import Tensor
from torch.utils._python_dispatch import TorchDispatchMode

#: Operators that only allocate or read metadata, launching no kernel.
NO_LAUNCH = frozenset({"aten.empty.memory_format", "aten.empty_strided.default", "aten.empty_like.default",
                       "aten.new_empty.default", "aten.new_empty_strided.default", "aten.set_.source_Storage",
                       "aten.set_.source_Storage_storage_offset", "aten.resize_.default", "aten.lift_fresh.default",
                       "aten.is_same_size.default", "aten.sym_size.int", "aten.sym_stride.int",
                       "aten.sym_numel.default", "aten.sym_storage_offset.default"})


class Updatable(Protocol):
    """An agent whose `update` takes a replay batch and demonstration windows (`fbcpr.core.protocols.OnlineAgent`)."""

    def update(self, batch: dict[str, Tensor], expert_windows: Tensor) -> Mapping[str, float]: ...


@dataclass
class OpCount:
    """The operators dispatched while something ran: `kernels` launch work, `views` only make views or read
    metadata; `ops` counts each operator's overload name (both kinds)."""

    kernels: int = 0
    views: int = 0
    ops: Counter[str] = field(default_factory=Counter)

    @property
    def total(self) -> int:
        return self.kernels + self.views

    def top(self, n: int = 10) -> str:
        """The n most frequent operators, as `name x count` pairs (where the kernels go)."""
        return ", ".join(f"{name} x{count}" for name, count in self.ops.most_common(n))


class _Counter(TorchDispatchMode):
    def __init__(self, count: OpCount) -> None:
        super().__init__()
        self.count = count

    def __torch_dispatch__(self, func: Any, types: Any, args: Any = (), kwargs: Any = None) -> Any:
        name = str(func)
        self.count.ops[name] += 1
        if func.is_view or name in NO_LAUNCH or func.namespace == "profiler":
            self.count.views += 1
        else:
            self.count.kernels += 1
        return func(*args, **(kwargs or {}))


def count_ops(fn: Callable[[], Any]) -> OpCount:
    """The operators `fn()` dispatches (its backward passes and optimiser steps included)."""
    count = OpCount()
    with _Counter(count):
        fn()
    return count


def count_update_ops(agent: Updatable, batch: dict[str, Tensor], windows: Tensor, warmup: int = 1) -> OpCount:
    """The operators of one `agent.update(batch, windows)`, after `warmup` uncounted updates on the same batch (the
    first update also creates the optimisers' state, which later ones do not). The agent is updated warmup + 1
    times."""
    for _ in range(warmup):
        agent.update(batch, windows)
    return count_ops(lambda: agent.update(batch, windows))


def count_update_kernels(agent: Updatable, batch: dict[str, Tensor], windows: Tensor, warmup: int = 1) -> int:
    """Kernels one update launches: its non-view aten operators (`count_update_ops`)."""
    return count_update_ops(agent, batch, windows, warmup).kernels
