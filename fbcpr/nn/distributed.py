"""Data-parallel training on `torch.distributed` (launched with torchrun): one process per rank, gloo on CPU, NCCL
on GPUs.

Every rank runs the same `Trainer` on its own envs, replay shard, demonstration windows and random streams (base seed
+ rank) and holds a full copy of the learner. Inside `Replicas.synchronized()` (the trainer wraps each
`agent.update` in it) two things keep the copies identical:

- gradients: a global optimiser pre-step hook (`torch.optim.optimizer.register_optimizer_step_pre_hook`) averages,
  before any optimiser steps, the gradients of every parameter of every optimiser seen so far that has a fresh
  gradient, in one all-reduce over a flat buffer per dtype and device. So FB-CPR's five optimisers after its one
  backward cost one all-reduce, and an imitation reward's own optimiser inside `fit` (AMP, NEAR, VIRL) is covered
  without the method knowing. DDP is not used: it wraps one module's forward, while an update here runs many
  modules (targets, detached-weight actor evaluations, a double backward for the gradient penalty) under several
  optimisers, some of them inside reward objects.
- normaliser statistics: `RunningNormalizer.update` merges its batch moments (count, mean, variance) over ranks
  before folding them in (`merge_moments`), so every rank normalises with the statistics of the global batch.

The rule for method authors: inside `update`, change trainable weights only through `optimizer.step()` on
gradients from `backward()`, and running statistics only through `RunningNormalizer.update`; anything else
(a hand-written in-place weight change from data) must be the same on every rank. Target networks follow their
(identical) online networks and need nothing. `Replicas.check_replicated` verifies the rule at start and at every
checkpoint, bit for bit.

A single process (no WORLD_SIZE in the environment, or WORLD_SIZE=1) gets `Replicas(rank=0, world_size=1)`, whose
methods are no-ops: training is exactly what it is without torch.distributed.
"""
from __future__ import annotations

import hashlib
import os
import weakref
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from datetime import timedelta
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import Tensor
from torch.optim.optimizer import register_optimizer_step_pre_hook

from fbcpr.core.errors import ConfigError

#: The replica group whose `synchronized()` block is running (hooks and normalisers consult it); None outside.
_ACTIVE: Replicas | None = None


def _grad(p: Tensor) -> Tensor:
    """The gradient of a parameter that the caller knows has one."""
    assert p.grad is not None, "gradient averaging got a parameter without a gradient"
    return p.grad


class DistributedError(RuntimeError):
    """A collective failed (a rank died, was killed, or hung past the timeout) or the ranks disagree."""


class Replicas:
    """This process's place in the data-parallel group, and the few collectives training needs."""

    def __init__(self, rank: int = 0, world_size: int = 1, local_rank: int = 0, local_world_size: int = 1,
                 device: torch.device | None = None, timeout_s: float = 0.0) -> None:
        self.rank, self.world_size = rank, world_size
        self.local_rank, self.local_world_size = local_rank, local_world_size
        self.device = device or torch.device("cpu")  # where collective tensors live: the GPU under NCCL, else host
        self.timeout_s = timeout_s
        self._hook: Any = None
        self._seen: list[weakref.ref[torch.optim.Optimizer]] = []  # optimisers in first-step order (same on every rank)
        # id(parameter) -> (parameter, its gradient as last averaged, that gradient's version), all by weak reference
        self._synced: dict[int, tuple[weakref.ref[Tensor], weakref.ref[Tensor], int]] = {}

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the one that writes logs, checkpoints and the reward-inference buffer."""
        return self.rank == 0

    # ------------------------------------------------------------------------------- error reporting
    @contextmanager
    def _collective(self, what: str) -> Iterator[None]:
        """Turn a failed collective into one clear DistributedError naming this rank and what it was doing."""
        try:
            yield
        except DistributedError:
            raise
        except RuntimeError as err:  # DistBackendError and DistNetworkError are RuntimeErrors
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise DistributedError(
                f"rank {self.rank} of {self.world_size}: lost the other ranks during {what} (one died, was killed, or "
                f"hung past train.dist_timeout_s = {self.timeout_s:g} s); the last checkpoint on disk is intact, "
                f"continue with --resume. Cause: {first}") from err

    # ------------------------------------------------------------------------------- synchronised updates
    @contextmanager
    def synchronized(self) -> Iterator[None]:
        """While inside, every optimiser step averages gradients over ranks and every running normaliser merges its
        batch statistics over ranks (see the module docstring). A no-op for one process."""
        global _ACTIVE
        if not self.enabled:
            yield
            return
        if self._hook is None:
            self._hook = register_optimizer_step_pre_hook(self._before_step)
        _ACTIVE = self
        try:
            yield
        finally:
            _ACTIVE = None

    def _before_step(self, optimizer: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        if _ACTIVE is not self:
            return
        if not any(ref() is optimizer for ref in self._seen):
            self._seen.append(weakref.ref(optimizer))
        fresh = {id(p): p for ref in self._seen if (opt := ref()) is not None for group in opt.param_groups
                 for p in group["params"] if p.grad is not None and not self._is_synced(p)}  # a shared one once
        if fresh:
            self.average_gradients(list(fresh.values()))

    def _is_synced(self, p: Tensor) -> bool:
        """Whether p.grad is the very tensor, unchanged, that the last average wrote (a new backward makes a new one,
        or bumps its version when it accumulates into it)."""
        mark, grad = self._synced.get(id(p)), p.grad
        return (mark is not None and grad is not None and mark[0]() is p and mark[1]() is grad
                and mark[2] == grad._version)

    def average_gradients(self, params: list[Tensor]) -> None:
        """p.grad := mean over ranks of p.grad, one all-reduce per (dtype, device) over a flat buffer."""
        groups: dict[tuple[torch.dtype, torch.device], list[Tensor]] = {}
        for p in params:
            groups.setdefault((_grad(p).dtype, _grad(p).device), []).append(p)
        with self._collective("the gradient all-reduce"):
            for group in groups.values():
                grads = [_grad(p) for p in group]
                flat = torch.cat([g.reshape(-1) for g in grads]).to(self.device)
                dist.all_reduce(flat)
                flat = flat.div_(self.world_size).to(grads[0].device)
                parts = flat.split([g.numel() for g in grads])
                torch._foreach_copy_(grads, [f.view_as(g) for f, g in zip(parts, grads)])
        for p in params:
            self._synced[id(p)] = (weakref.ref(p), weakref.ref(_grad(p)), _grad(p)._version)

    # ------------------------------------------------------------------------------- agreement and gathering
    def agree(self, stop: bool, ready: int) -> tuple[bool, int]:
        """(any rank wants to stop, the smallest `ready` count over ranks): the decisions every rank must take
        together (ending the run, starting updates once every replay shard holds a batch)."""
        if not self.enabled:
            return stop, ready
        t = torch.tensor([float(stop), -float(ready)], dtype=torch.float64, device=self.device)
        with self._collective("the step agreement"):
            dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t[0].item()), int(-t[1].item())

    def sum(self, values: np.ndarray) -> np.ndarray:
        """Element-wise sum of a float64 array over ranks."""
        if not self.enabled:
            return values
        t = torch.as_tensor(np.asarray(values, dtype=np.float64), device=self.device).clone()
        with self._collective("a sum over ranks"):
            dist.all_reduce(t)
        return t.cpu().numpy()

    def mean_metrics(self, metrics: Mapping[str, float]) -> Mapping[str, float]:
        """Metrics averaged over ranks (every rank logs the same keys: they run the same code)."""
        if not self.enabled or not metrics:
            return metrics
        keys = sorted(metrics)
        total = self.sum(np.array([metrics[k] for k in keys], dtype=np.float64))
        return {k: float(v) / self.world_size for k, v in zip(keys, total)}

    def merge_moments(self, n: float, mean: Tensor, var: Tensor) -> tuple[float, Tensor, Tensor]:
        """Exact (count, mean, population variance) of the union of every rank's batch, in float64 (Chan et al.)."""
        d = mean.shape[0]
        local = torch.cat([mean.new_tensor([n]), mean, var]).to(device=self.device, dtype=torch.float64)
        parts = self._gather(local, "the normaliser merge").to(mean.device)
        counts, means, vars_ = parts[:, :1], parts[:, 1:d + 1], parts[:, d + 1:]
        total = counts.sum()
        if total == 0:
            return 0.0, mean, var
        g_mean = (counts * means).sum(0) / total
        g_var = (counts * (vars_ + (means - g_mean).square())).sum(0) / total
        return float(total), g_mean, g_var

    def check_replicated(self, tensors: dict[str, Tensor], what: str) -> None:
        """Raise DistributedError unless every rank holds bit-identical `tensors` (a SHA-256 over their bytes)."""
        if not self.enabled:
            return
        h = hashlib.sha256()
        for k in sorted(tensors):
            t = tensors[k].detach().cpu().reshape(-1)
            h.update(k.encode())
            h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
        mine = torch.tensor(list(h.digest()), dtype=torch.uint8, device=self.device)
        every = self._gather(mine, f"the replica check of {what}")
        differ = [r for r in range(self.world_size) if not torch.equal(every[r], every[0])]
        if differ:
            raise DistributedError(f"{what} differs between rank 0 and rank(s) {differ}: the ranks run different "
                                   "configs or code, or an update changed weights outside optimizer.step() "
                                   "(see fbcpr.nn.distributed)")

    def _gather(self, t: Tensor, what: str) -> Tensor:
        """(world_size, *t.shape): every rank's `t`, in rank order."""
        parts = [torch.empty_like(t) for _ in range(self.world_size)]
        with self._collective(what):
            dist.all_gather(parts, t)
        return torch.stack(parts)

    def close(self) -> None:
        """Remove the optimiser hook and leave the process group."""
        if self._hook is not None:
            self._hook.remove()
            self._hook = None
        if self.enabled and dist.is_initialized():
            dist.destroy_process_group()


def active() -> Replicas | None:
    """The replica group inside whose `synchronized()` block we are (None: local, single-process behaviour)."""
    return _ACTIVE


def launched_world_size() -> int:
    """WORLD_SIZE set by torchrun (1 without it)."""
    return int(os.environ.get("WORLD_SIZE", "1"))


def launched_rank() -> int:
    """RANK set by torchrun (0 without it): CLIs print from rank 0 only."""
    return int(os.environ.get("RANK", "0")) if launched_world_size() > 1 else 0


def setup(device: torch.device, timeout_s: float, backend: str = "auto") -> tuple[Replicas, torch.device]:
    """Join the process group torchrun describes in the environment (RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, ...).
    On CUDA each local rank takes GPU LOCAL_RANK (modulo the GPUs there are) and `auto` means NCCL, which needs one
    GPU per process; gloo (the CPU's, or `train.dist_backend: gloo` to share a GPU) reduces through host memory.
    Returns the replicas and this rank's device. Without torchrun (or with one process) nothing is initialised."""
    world = launched_world_size()
    if world <= 1:
        return Replicas(), device
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    local_world = int(os.environ.get("LOCAL_WORLD_SIZE", "1"))
    if backend == "auto":
        backend = "nccl" if device.type == "cuda" else "gloo"
    if backend == "nccl" and (device.type != "cuda" or local_world > torch.cuda.device_count()):
        raise ConfigError(f"train.dist_backend: NCCL needs one GPU per process, and {local_world} processes on this "
                          f"machine train on {device.type} with {torch.cuda.device_count()} GPU(s); start one "
                          "process per GPU (--nproc_per_node), or set gloo")
    if device.type == "cuda":
        device = torch.device("cuda", local_rank % torch.cuda.device_count())
        torch.cuda.set_device(device)
    collective = device if backend == "nccl" else torch.device("cpu")
    replicas = Replicas(rank, world, local_rank, local_world, collective, timeout_s)
    with replicas._collective("process-group start-up"):
        if not dist.is_initialized():
            dist.init_process_group(backend, rank=rank, world_size=world, timeout=timedelta(seconds=timeout_s))
    return replicas, device


def run_plan(replicas: Replicas, num_envs: int, batch_size: int, updates: int, env_steps: int) -> str:
    """What a data-parallel run runs, in one line for rank 0 to print at its start, so that a log tells N processes
    training one model from N copies of one run: `updates` updates per phase of `env_steps` global env steps."""
    w = replicas.world_size
    backend = dist.get_backend() if dist.is_initialized() else "none"
    return (f"data-parallel: {w} processes ({backend}), each with {num_envs} envs and a batch of {batch_size} "
            f"({w * num_envs} envs and {w * batch_size} samples per update in all); {updates} updates per "
            f"{env_steps:,} env steps over all processes: a global update-to-data ratio of {updates / env_steps:.3g}")
