"""Bounds on motion inputs, checked before any work whose size the input decides.

A damaged or hostile file (a frame rate of 1e-6, a frame lasting an hour, a header claiming 10^12 frames) must fail
in milliseconds with a one-line error, not grow for minutes until the kernel kills the process.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from humanoid_env.model import CONTROL_HZ

#: Environment variable that raises or lowers the clip duration cap (seconds).
MAX_SECONDS_ENV = "FBCPR_MAX_CLIP_SECONDS"
#: Default cap on a clip's duration: 10 minutes, 18,000 frames at 30 Hz (about 50 MB in memory).
DEFAULT_MAX_SECONDS = 600.0
#: Source frame times must lie in [1 ms, 1 s]: 1 to 1000 frames per second.
MIN_FRAME_SECONDS = 1e-3
MAX_FRAME_SECONDS = 1.0
#: Largest single array a motion .npz may declare, and largest text motion file (JSON, BVH), in bytes.
MAX_ARRAY_BYTES = 1 << 30
MAX_TEXT_BYTES = 256 << 20
#: Deepest joint nesting accepted in a BVH hierarchy (human rigs are about 10 deep).
MAX_BVH_DEPTH = 200


def max_clip_seconds() -> float:
    """The duration cap: $FBCPR_MAX_CLIP_SECONDS, else 600 s; one setting for imports and loads alike."""
    raw = os.environ.get(MAX_SECONDS_ENV)
    if raw is None:
        return DEFAULT_MAX_SECONDS
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{MAX_SECONDS_ENV}={raw!r}: must be a positive number of seconds")
    return value


def max_clip_frames() -> int:
    """Most frames a 30 Hz clip may have under the duration cap."""
    return int(max_clip_seconds() * CONTROL_HZ) + 1


def too_long(seconds: float, where: str) -> str:
    """The message for a clip over the cap: it names the limit and the setting that changes it."""
    return (f"{where}: lasts {seconds:.4g} s, over the {max_clip_seconds():.4g} s limit on a clip "
            f"(set {MAX_SECONDS_ENV} to allow longer clips)")


def check_frame_times(durations: np.ndarray | float, where: str, error: type[Exception], repeats: int = 1) -> None:
    """Raise `error` unless each source frame time is finite and in [1 ms, 1 s], and the clip lasts between one
    30 Hz frame step and the duration cap: the resampled clip then has 2 to max_clip_frames() frames.

    `durations` holds each frame's time, or one time that `repeats` frames share (a fixed frame rate)."""
    durations = np.atleast_1d(np.asarray(durations, dtype=np.float64))
    if not np.all(np.isfinite(durations)):
        raise error(f"{where}: frame time must be finite, got {durations[~np.isfinite(durations)][0]}")
    bad = (durations < MIN_FRAME_SECONDS) | (durations > MAX_FRAME_SECONDS)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise error(f"{where}: frame time {durations[i]:.4g} s (frame {i}) is outside [{MIN_FRAME_SECONDS:g}, "
                    f"{MAX_FRAME_SECONDS:g}] s, i.e. {1 / MAX_FRAME_SECONDS:g} to {1 / MIN_FRAME_SECONDS:g} fps")
    total = float(durations.sum()) * repeats
    if total * CONTROL_HZ < 1 - 1e-6:
        raise error(f"{where}: lasts {total:.4g} s, too short for 2 frames at {CONTROL_HZ} Hz")
    if total > max_clip_seconds():
        raise error(too_long(total, where))


def check_input_file(path: Path, error: type[Exception], max_bytes: int | None = None) -> None:
    """Raise `error` unless `path` is a regular file (a named pipe would block the reader forever) no larger
    than `max_bytes`."""
    try:
        st = os.stat(path)
    except OSError as err:
        raise error(f"{path}: cannot read ({err.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(f"{path}: {st.st_size / 2**20:.0f} MiB, larger than the {max_bytes / 2**20:.0f} MiB limit "
                    "on a text motion file")


def read_text(path: Path, error: type[Exception]) -> str:
    """A text motion file (JSON, BVH), checked to be a regular file of bounded size first."""
    check_input_file(path, error, MAX_TEXT_BYTES)
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise error(f"{path}: cannot read ({err})") from None
    except MemoryError:
        raise error(f"{path}: too large to read into memory") from None
