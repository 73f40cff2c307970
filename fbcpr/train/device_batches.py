"""Update batches drawn on the training device (`train.device_buffer`).

Drawn on the host, every update's batch is gathered by numpy from the replay buffer and the motion frames, then copied
to the GPU while the GPU waits: about 10 ms an update on an H100, as long as a graphed update itself. `DeviceBatches`
keeps a copy of the buffer's training fields and of the motion frames on the device and draws each batch there with its
own generator, so a draw is a few kernels queued behind the previous update and the host never waits for it. The replay
buffer on the host stays the record (checkpoints, reward samples, rollout latents); the copy follows it row by row as
transitions are added.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from fbcpr.train.buffer import ReplayBuffer

#: rows copied to the device at once when a whole buffer is (re)loaded: bounds the host memory of a memmap read
RELOAD_CHUNK = 65_536


class DeviceBatches:
    """Replay batches and demonstration windows sampled on `device` from copies of `buffer` and `library`.

    Clips are drawn by the library's priorities (re-read whenever the library replaces them), windows start
    uniformly inside the clip, and transitions uniformly over the filled buffer, as the host draw does; the random
    numbers differ, from this object's own generator (saved in checkpoints by the trainer)."""

    def __init__(self, buffer: ReplayBuffer, library: Any, fields: tuple[str, ...], device: torch.device,
                 seed: int) -> None:
        missing = [f for f in fields if f not in buffer.specs]
        if missing:
            raise ValueError(f"DeviceBatches: the replay buffer has no field {missing[0]!r}")
        self.buffer, self.library, self.fields, self.device = buffer, library, tuple(fields), device
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.rows = {f: torch.zeros((buffer.capacity, *buffer.specs[f]), device=device) for f in self.fields}
        self.frames = torch.as_tensor(np.asarray(library.frames, dtype=np.float32), device=device)
        self.lengths = torch.as_tensor(library.lengths, dtype=torch.long, device=device)
        self.offsets = torch.as_tensor(library.offsets, dtype=torch.long, device=device)
        self._cdf: dict[int, Tensor] = {}   # per window length: clip cumulative probabilities
        self._priorities: np.ndarray | None = None  # the library's array the cdfs were made from
        self.reload()

    @staticmethod
    def bytes_needed(capacity: int, specs: dict[str, tuple[int, ...]], fields: tuple[str, ...]) -> int:
        """Device memory of the buffer copy (the motion frames are small beside it)."""
        return 4 * capacity * sum(int(np.prod(specs[f])) for f in fields)

    def added(self, rows: np.ndarray) -> None:
        """Copy the buffer rows `ReplayBuffer.add` just wrote."""
        if len(rows) == 0:
            return
        idx = torch.as_tensor(rows, dtype=torch.long, device=self.device)
        for f in self.fields:
            self.rows[f][idx] = torch.from_numpy(np.ascontiguousarray(self.buffer.data[f][rows])).to(self.device)

    def reload(self) -> None:
        """Copy the whole filled buffer (at the start, and after a resume has loaded it)."""
        for start in range(0, len(self.buffer), RELOAD_CHUNK):
            stop = min(start + RELOAD_CHUNK, len(self.buffer))
            for f in self.fields:
                chunk = np.ascontiguousarray(self.buffer.data[f][start:stop])
                self.rows[f][start:stop] = torch.from_numpy(chunk).to(self.device)

    def sample(self, n: int, windows: int, length: int, clips: bool = False) -> tuple[dict[str, Tensor], Tensor]:
        """n transitions uniformly with replacement (the trainer's fields) and `windows` demonstration windows of
        `length` consecutive frames, (windows, length, obs_dim), all on the device; with `clips`, the batch's
        "window_clip" holds the library index of each window's clip (windows,)."""
        size = len(self.buffer)
        if size == 0:
            raise RuntimeError("DeviceBatches.sample: the replay buffer is empty")
        idx = torch.randint(size, (n,), device=self.device, generator=self.generator)
        batch = {f: self.rows[f].index_select(0, idx) for f in self.fields}
        frames, clip = self._windows(windows, length)
        if clips:
            batch["window_clip"] = clip
        return batch, frames

    def _windows(self, n: int, length: int) -> tuple[Tensor, Tensor]:
        u = torch.rand(2, n, device=self.device, generator=self.generator)
        clip = torch.searchsorted(self._clip_cdf(length), u[0], right=True)
        start = (u[1] * (self.lengths[clip] - length + 1)).long()
        frame = (self.offsets[clip] + start)[:, None] + torch.arange(length, device=self.device)
        return self.frames[frame], clip

    def _clip_cdf(self, length: int) -> Tensor:
        """Cumulative clip probabilities for windows of `length`: priorities of the clips that are long enough,
        recomputed (one small copy to the device) only after the library's priorities were replaced."""
        if self._priorities is not self.library.priorities:
            self._priorities, self._cdf = self.library.priorities, {}
        if length not in self._cdf:
            p = np.asarray(self._priorities, dtype=np.float64) * (np.asarray(self.library.lengths) >= length)
            if p.sum() <= 0:
                raise ValueError(f"DeviceBatches: no clip has {length} frames with a positive priority")
            cdf = np.cumsum(p) / p.sum()
            cdf[np.flatnonzero(p)[-1]:] = 2.0  # above any u < 1, even where float32 rounds the sum below 1
            self._cdf[length] = torch.as_tensor(cdf, dtype=torch.float32, device=self.device)
        return self._cdf[length]

    def state(self) -> Tensor:
        """The generator's state, for an exact resume."""
        return self.generator.get_state()

    def load_state(self, state: Tensor) -> None:
        self.generator.set_state(state)
