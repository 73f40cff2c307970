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

A `torch.compile`d function runs eagerly under a dispatch mode, so a compiled update is counted from the profiler
instead (`count_launches`): every kernel that inductor generated (on the CPU, each C++ kernel carries a profiler
marker when compiled under `KERNEL_MARKERS`), plus every aten operator that launches work and is called from
outside any other operator (the calls from Python, from autograd's backward and from a compiled graph's wrapper to
external kernels such as `bmm`; an operator's own inner calls are its kernel's business). Composite operators that
the dispatcher decomposes (`CompositeImplicitAutograd`) count as the operators they become, views and metadata apart,
as above: on an eager update the two counts agree operator for operator (`tests/test_kernel_count.py`). Inductor
generates C++ on the CPU and Triton on a GPU, which fuse the same graph by their own rules, so a compiled region's
count is the CPU's.
"""
from __future__ import annotations

import contextlib
import re
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any, Protocol

import torch
from torch import Tensor
from torch.utils._python_dispatch import TorchDispatchMode

#: Operators that only allocate or read metadata, launching no kernel.
NO_LAUNCH = frozenset({"aten.empty.memory_format", "aten.empty_strided.default", "aten.empty_like.default",
                       "aten.new_empty.default", "aten.new_empty_strided.default", "aten.set_.source_Storage",
                       "aten.set_.source_Storage_storage_offset", "aten.resize_.default", "aten.lift_fresh.default",
                       "aten.is_same_size.default", "aten.sym_size.int", "aten.sym_stride.int",
                       "aten.sym_numel.default", "aten.sym_storage_offset.default"})


#: The name of an inductor kernel's profiler marker: graph_<n>_cpp_fused_<ops>_<k> (`KERNEL_MARKERS`).
INDUCTOR_KERNEL = re.compile(r"^graph_\d+_cpp_")


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


@contextlib.contextmanager
def kernel_markers() -> Iterator[None]:
    """Inductor's C++ kernels compiled inside carry a profiler marker each (its `cpp.enable_kernel_profile`), which
    `count_launches` counts. The marker is part of the generated code: a function must be compiled (first called)
    inside."""
    import torch._inductor.config as inductor_config

    with inductor_config.patch({"cpp.enable_kernel_profile": True}):
        yield


@cache
def _kind(name: str) -> str:
    """An event's name as 'kernel' (launches work), 'view' (views and metadata), or 'other' (a composite operator
    that the dispatcher decomposes, or no operator at all)."""
    if INDUCTOR_KERNEL.match(name):
        return "kernel"
    if not name.startswith("aten::"):
        return "other"
    packet = getattr(torch.ops.aten, name[len("aten::"):], None)
    if packet is None:
        return "other"
    overloads = [getattr(packet, o) for o in packet.overloads()]
    if overloads and all(_composite(o) for o in overloads):
        return "other"
    if any(o.is_view or str(o) in NO_LAUNCH for o in overloads):
        return "view"
    return "kernel"


def _composite(overload: Any) -> bool:
    """Whether the dispatcher decomposes this overload above autograd (TorchScript-only overloads, which the
    dispatcher does not know, never run as kernels either)."""
    try:
        return bool(overload.has_kernel_for_dispatch_key(torch._C.DispatchKey.CompositeImplicitAutograd))
    except RuntimeError:
        return True


def count_launches(fn: Callable[[], Any]) -> OpCount:
    """The kernels `fn()` launches, counted from the profiler's events, compiled regions included (see the module's
    docstring); `ops` names each counted kernel (an inductor kernel by its marker)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        fn()
    count = OpCount()
    for event in prof.events():
        kind = _kind(event.name)
        if kind == "other":
            continue
        parent = event.cpu_parent
        while parent is not None and _kind(parent.name) == "other":
            parent = parent.cpu_parent
        if parent is not None:  # inside another operator's kernel
            continue
        count.ops[event.name] += 1
        if kind == "kernel":
            count.kernels += 1
        else:
            count.views += 1
    return count


def count_compiled_update(agent: Updatable, batch: dict[str, Tensor], windows: Tensor, warmup: int = 1) -> OpCount:
    """`count_update_ops` for an update that may run compiled code: the warm-up updates (where it compiles) run under
    `kernel_markers`, the counted one under `count_launches`. Code compiled earlier in this process is dropped first
    (`torch._dynamo.reset`): another agent of the same class would reuse it, without the markers."""
    torch._dynamo.reset()
    with kernel_markers():
        for _ in range(warmup):
            agent.update(batch, windows)
    return count_launches(lambda: agent.update(batch, windows))
