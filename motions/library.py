"""A set of clips to sample from: observation windows for the ER_FB encodings, initial states for the env's MoCap
init, and per-motion priorities driven by tracking EMD (FB-CPR App. C: EMD clipped to [0.5, 5], bins of 0.5)."""
from __future__ import annotations

import fnmatch
import hashlib
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from motions.clip import Clip, load_clip
from motions.demonstrations import clip_paths

EMD_CLIP = (0.5, 5.0)
EMD_BIN_WIDTH = 0.5


def emd_bins(emd: np.ndarray) -> np.ndarray:
    """Bin index of each EMD after clipping to [0.5, 5]: 10 bins, the last one holding EMD >= 5."""
    clipped = np.clip(np.asarray(emd, dtype=np.float64), *EMD_CLIP)
    return np.floor((clipped - EMD_CLIP[0]) / EMD_BIN_WIDTH + 1e-9).astype(int)


def priorities_from_emd(emd: np.ndarray) -> np.ndarray:
    """priority(m) = 1 / |bin(m)|: each occupied bin gets the same total sampling mass."""
    bins = emd_bins(emd)
    counts = np.bincount(bins, minlength=bins.max() + 1)
    return 1.0 / counts[bins]


def split_name(name: str, test_fraction: float) -> bool:
    """True when a clip belongs to the test split; a hash of the name, so it is stable across runs and machines."""
    h = int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "big")
    return h / 2.0**64 < test_fraction


def matching_names(names: Sequence[str], patterns: Sequence[str]) -> np.ndarray:
    """(names,) bool: which names match any of the shell-style `patterns` (`fnmatch`, case-sensitive)."""
    return np.array([any(fnmatch.fnmatchcase(n, p) for p in patterns) for n in names], dtype=bool)


class MotionLibrary:
    """Clips in memory with flat arrays for vectorized sampling."""

    def __init__(self, clips: Sequence[Clip]):
        if len(clips) == 0:
            raise ValueError("MotionLibrary: no clips given")
        names = [c.name for c in clips]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"MotionLibrary: duplicate clip names {dupes}")
        self.clips: list[Clip] = list(clips)
        self.names: list[str] = names
        self.lengths = np.array([c.n_frames for c in clips])
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        self._obs = np.concatenate([c.obs for c in clips]).astype(np.float32)
        self._qpos = np.concatenate([c.qpos for c in clips])
        self._qvel = np.concatenate([c.qvel for c in clips])
        self.priorities = np.ones(len(clips))

    @classmethod
    def load(cls, source: str | os.PathLike | Iterable[str | os.PathLike]) -> MotionLibrary:
        """From a folder of clip `.npz` files (sorted by file name; a demonstration folder's actions files are
        skipped, so its motions serve as clips too) or an explicit list of files."""
        if isinstance(source, (str, os.PathLike)):
            folder = Path(source)
            if not folder.is_dir():
                raise FileNotFoundError(f"MotionLibrary: {folder} is not a folder of clips")
            paths = clip_paths(folder)
            if not paths:
                raise ValueError(f"MotionLibrary: no .npz clips in {folder}")
        else:
            paths = [Path(p) for p in source]
        return cls([load_clip(p) for p in paths])

    @property
    def frames(self) -> np.ndarray:
        """Every clip's observations, concatenated (clip m's frames begin at row offsets[m]): what a sampler that
        keeps its own copy of the frames (on a GPU, say) copies."""
        return self._obs

    def __len__(self) -> int:
        return len(self.clips)

    @property
    def total_seconds(self) -> float:
        return float(sum(c.seconds for c in self.clips))

    def split(self, test_fraction: float = 0.1) -> tuple[MotionLibrary, MotionLibrary | None]:
        """Deterministic (train, test) split by name hash; test is None when no clip falls into it."""
        is_test = [split_name(n, test_fraction) for n in self.names]
        train = [c for c, t in zip(self.clips, is_test) if not t]
        test = [c for c, t in zip(self.clips, is_test) if t]
        if not train:
            raise ValueError(f"MotionLibrary.split: test_fraction={test_fraction} leaves no training clips")
        return MotionLibrary(train), (MotionLibrary(test) if test else None)

    def set_priorities_from_emd(self, emd: dict[str, float]) -> None:
        """Replace the sampling priorities from per-motion tracking EMD (one value for every clip)."""
        unknown = sorted(set(emd) - set(self.names))
        missing = sorted(set(self.names) - set(emd))
        if unknown or missing:
            raise ValueError(f"set_priorities_from_emd: unknown names {unknown[:5]}, missing names {missing[:5]}")
        values = np.array([emd[n] for n in self.names], dtype=np.float64)
        if not np.all(np.isfinite(values)):
            raise ValueError("set_priorities_from_emd: EMD values must be finite")
        self.priorities = priorities_from_emd(values)

    def _pick(self, rng: np.random.Generator, n: int, allowed: np.ndarray | None = None) -> np.ndarray:
        p = self.priorities.copy()
        if allowed is not None:
            p = p * allowed
        if p.sum() <= 0:
            raise ValueError("MotionLibrary: no clip can be sampled")
        return rng.choice(len(self.clips), size=n, p=p / p.sum())

    def sample_windows(self, rng: np.random.Generator, n: int, length: int) -> np.ndarray:
        """(n, length, 358) windows of consecutive observations from clips drawn by priority."""
        return self.sample_window_clips(rng, n, length)[0]

    def sample_window_clips(self, rng: np.random.Generator, n: int, length: int) -> tuple[np.ndarray, np.ndarray]:
        """`sample_windows` and the index of the clip each window came from (n,), for losses that treat some
        clips apart (`agent.anchor_free`)."""
        allowed = self.lengths >= length
        if not allowed.any():
            raise ValueError(f"sample_windows: no clip has {length} frames (longest has {self.lengths.max()})")
        m = self._pick(rng, n, allowed)
        start = (rng.random(n) * (self.lengths[m] - length + 1)).astype(int)
        idx = (self.offsets[m] + start)[:, None] + np.arange(length)[None]
        return self._obs[idx], m

    def matching(self, patterns: Sequence[str]) -> np.ndarray:
        """(clips,) bool: the clips whose name matches any of the shell-style `patterns`."""
        return matching_names(self.names, patterns)

    def sample_states(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(qpos (n,76), qvel (n,75)): a clip by priority, then a frame uniformly inside it (the MoCap init)."""
        m = self._pick(rng, n)
        frame = (rng.random(n) * self.lengths[m]).astype(int)
        idx = self.offsets[m] + frame
        return self._qpos[idx].copy(), self._qvel[idx].copy()
