"""An update's metrics, read from the device only when someone looks at them.

Turning a GPU tensor into Python floats waits for every kernel queued before it. Done after each update, that wait
keeps the host from queueing the next update (or sampling its batch) while the GPU still runs this one, and a
replayed CUDA graph (`fbcpr.nn.cuda_graph`) then runs no faster than the host loop around it. The trainer reads
metrics at log rows and progress refreshes, tens of updates apart, so an update returns a `LazyMetrics` and the
copy happens there, once.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping

import torch
from torch import Tensor


class LazyMetrics(Mapping[str, float]):
    """Named scalar metrics held as one device tensor; the first read copies them all to the host at once.

    Later updates may overwrite the tensors an update returned (a CUDA graph's static outputs), so they are stacked
    into a new tensor when the metrics are made: a copy queued on the device, which does not wait for it. `extra`:
    metrics that are host floats already."""

    def __init__(self, values: Mapping[str, Tensor], extra: Mapping[str, float] | None = None) -> None:
        self._keys = list(values)
        self._stacked: Tensor | None = torch.stack([v.detach().float().reshape(()) for v in values.values()]) \
            if values else None
        self._floats: dict[str, float] | None = None if values else {}
        self._extra = dict(extra or {})

    def _read(self) -> dict[str, float]:
        if self._floats is None:
            assert self._stacked is not None
            self._floats = dict(zip(self._keys, self._stacked.tolist()))
            self._stacked = None  # the device memory is not held past the read
        return self._floats

    def __getitem__(self, key: str) -> float:
        if key in self._extra:
            return self._extra[key]
        return self._read()[key]

    def __iter__(self) -> Iterator[str]:
        yield from self._extra
        yield from (k for k in self._keys if k not in self._extra)

    def __len__(self) -> int:
        return len(self._extra) + sum(k not in self._extra for k in self._keys)

    def __contains__(self, key: object) -> bool:
        return key in self._extra or key in self._keys

    @property
    def read(self) -> bool:
        """Whether the values were copied to the host already (tests check that an update alone does not)."""
        return self._floats is not None
