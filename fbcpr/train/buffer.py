"""Online replay buffer: a ring of (s, a, s', z, qpos, qvel, terminated) with optional np.memmap storage.

qpos/qvel are those of the next state s', the state a reward is evaluated on, so a subsample of
(next_obs, qpos, qvel) is exactly what reward prompts need (`reward_inference_sample`).
Large buffers (the paper's 5M transitions of the humanoid are ~15 GB) live in memory-mapped files.

The trainer adds one transition per env per step, so an env's previous transition sits `stride` (= num_envs)
rows back; `sample(..., history=H)` walks back that way to give each transition the states of its episode before
it (a sequence reward's input, VIRL's), without storing sequences. An optional "frame" field (a grey uint8 image of
s', rendered once at collection for VIRL's video input) gives, with `frames=True`, the frames of that same walk.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

FIELDS = ("obs", "action", "next_obs", "z", "qpos", "qvel", "terminated")
FRAME = "frame"  # optional field: a (size, size) uint8 grey image of s' (4 KiB a transition at 64x64)


def transition_specs(obs_dim: int, action_dim: int, z_dim: int, nq: int, nv: int) -> dict[str, tuple[int, ...]]:
    """Per-transition shapes of every stored field."""
    return {"obs": (obs_dim,), "action": (action_dim,), "next_obs": (obs_dim,), "z": (z_dim,), "qpos": (nq,),
            "qvel": (nv,), "terminated": ()}


class ReplayBuffer:
    """Fixed-capacity FIFO of transitions, stored as float32 arrays (memmapped when `memmap_dir` is given)."""

    def __init__(self, capacity: int, specs: dict[str, tuple[int, ...]], memmap_dir: str | Path | None = None,
                 stride: int = 1) -> None:
        missing = [f for f in FIELDS if f not in specs]
        if missing:
            raise ValueError(f"ReplayBuffer specs: missing fields {missing}")
        self.capacity, self.specs, self.stride = capacity, dict(specs), stride
        self.size, self.pos = 0, 0
        self.dropped = 0  # transitions refused by `add` for NaN or inf values
        self.memmap_dir = Path(memmap_dir) if memmap_dir is not None else None
        if self.memmap_dir is not None:
            self.memmap_dir.mkdir(parents=True, exist_ok=True)
        self.data = {k: self._alloc(k, (capacity, *shape)) for k, shape in specs.items()}

    @staticmethod
    def dtype(name: str) -> type:
        """uint8 for frames, float32 for everything else."""
        return np.uint8 if name == FRAME else np.float32

    def _alloc(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        if self.memmap_dir is None:
            return np.zeros(shape, dtype=self.dtype(name))
        return np.lib.format.open_memmap(self.memmap_dir / f"{name}.npy", mode="w+", dtype=self.dtype(name),
                                         shape=shape)

    @staticmethod
    def bytes_needed(capacity: int, specs: dict[str, tuple[int, ...]]) -> int:
        return capacity * sum(np.dtype(ReplayBuffer.dtype(k)).itemsize * int(np.prod(s)) for k, s in specs.items())

    def __len__(self) -> int:
        return self.size

    def add(self, batch: dict[str, np.ndarray]) -> np.ndarray:
        """Append k transitions (every field with leading dim k), overwriting the oldest when full; returns the
        rows written (for a copy that mirrors them, `fbcpr.train.device_batches`).

        A transition with a NaN or inf in any field (float32 overflow of a huge but finite state included) is
        dropped and counted in `dropped`: one stored inf would break every later update and reward prompt."""
        k = len(batch["obs"])
        arrays = {}
        for name, shape in self.specs.items():
            arr: np.ndarray = np.asarray(batch[name], dtype=self.dtype(name))
            if arr.shape != (k, *shape):
                raise ValueError(f"ReplayBuffer.add: field {name!r} has shape {arr.shape}, expected {(k, *shape)}")
            arrays[name] = arr
        finite = np.ones(k, dtype=bool)
        for arr in arrays.values():
            finite &= np.isfinite(arr.reshape(k, -1)).all(axis=1)
        if not finite.all():
            self.dropped += int(k - finite.sum())
            arrays = {name: arr[finite] for name, arr in arrays.items()}
            k = int(finite.sum())
        idx = (self.pos + np.arange(k)) % self.capacity
        for name in self.specs:
            self.data[name][idx] = arrays[name]
        self.pos = int((self.pos + k) % self.capacity)
        self.size = int(min(self.size + k, self.capacity))
        return idx

    def sample(self, rng: np.random.Generator, n: int, fields: tuple[str, ...] = FIELDS,
               history: int = 0, frames: bool = False) -> dict[str, torch.Tensor]:
        """n transitions uniformly with replacement, as tensors (float32; uint8 frames); with history=H > 0 also
        "history", (n, H, obs_dim): the episode's states s_{t-H+1}..s_t ending at each obs, the earliest one
        repeated where the episode (or the buffer) began less than H steps before; with `frames` also "frames",
        (n, H + 1, size, size) uint8: the frames of s_{t-H+1}..s_{t+1} (the reset state has none: the episode's
        first frame stands in for it)."""
        if frames and FRAME not in self.data:
            raise ValueError("ReplayBuffer.sample: frames asked of a buffer without a 'frame' field")
        if self.size == 0:
            raise RuntimeError("ReplayBuffer.sample: the buffer is empty")
        idx = np.sort(rng.integers(0, self.size, size=n))  # sorted: sequential reads on memmaps
        out = {k: torch.from_numpy(np.ascontiguousarray(self.data[k][idx])) for k in fields}
        if history > 0:
            rows = self._rows(idx, history + 1 if frames else history)
            out["history"] = torch.from_numpy(self.data["obs"][rows[:, -history:]])
            if frames:
                out["frames"] = torch.from_numpy(self.data[FRAME][rows])
        return out

    def _rows(self, idx: np.ndarray, length: int) -> np.ndarray:
        """(n, length) rows of the episode's `length` transitions ending at idx, walking back `stride` rows while
        the previous row's next_obs is this row's obs (the same env's episode: a reset breaks the equality); the
        earliest row is repeated where the episode (or the buffer) began less than `length` steps before."""
        obs, nxt = self.data["obs"], self.data["next_obs"]
        rows = np.empty((len(idx), length), dtype=np.int64)
        rows[:, -1] = idx
        cur, alive = idx.copy(), np.ones(len(idx), dtype=bool)
        for j in range(length - 2, -1, -1):  # over time steps, batched over the sample
            age = (cur - self.pos) % self.capacity if self.size == self.capacity else cur  # rows older than cur
            prev = (cur - self.stride) % self.capacity
            alive &= age >= self.stride
            alive[alive] = (nxt[prev[alive]] == obs[cur[alive]]).all(axis=1)
            cur = np.where(alive, prev, cur)
            rows[:, j] = cur
        return rows

    def reward_inference_sample(self, max_n: int, rng: np.random.Generator | None = None) -> dict[str, np.ndarray]:
        """Up to max_n distinct transitions' (next_obs, qpos, qvel): the checkpoint's reward buffer."""
        rng = np.random.default_rng(0) if rng is None else rng
        n = min(max_n, self.size)
        idx = np.sort(rng.choice(self.size, size=n, replace=False))
        return {"next_obs": np.asarray(self.data["next_obs"][idx]), "qpos": np.asarray(self.data["qpos"][idx]),
                "qvel": np.asarray(self.data["qvel"][idx])}

    def state(self) -> tuple[dict[str, torch.Tensor], dict[str, int]]:
        """Filled part of the buffer, for an exact resume."""
        return ({k: torch.from_numpy(np.asarray(v[: self.size])) for k, v in self.data.items()},
                {"size": self.size, "pos": self.pos, "capacity": self.capacity})

    def load_state(self, tensors: dict[str, torch.Tensor], meta: dict[str, int]) -> None:
        size = int(meta["size"])
        if size > self.capacity:
            raise ValueError(f"replay buffer: saved size {size} exceeds capacity {self.capacity}")
        for k in self.specs:
            if k not in tensors or tuple(tensors[k].shape) != (size, *self.specs[k]):
                raise ValueError(f"replay buffer: field {k!r} missing or of the wrong shape")
            self.data[k][:size] = tensors[k].numpy()
        self.size, self.pos = size, int(meta["pos"]) % self.capacity
