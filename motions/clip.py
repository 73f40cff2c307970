"""The motion clip: one state trajectory of our humanoid at 30 Hz, stored as a pickle-free `.npz`."""
from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from humanoid_env.model import CONTROL_HZ, NQ, NV
from humanoid_env.observation import OBS_DIM
from motions.limits import max_clip_frames, too_long
from motions.npz import read_npz

FPS = CONTROL_HZ
MIN_FRAMES = 2
#: Fastest root motion a clip may have (m/s): well above a sprint (about 12 m/s), far below a 50 m teleport.
MAX_ROOT_SPEED = 30.0
_KEYS = ("qpos", "qvel", "obs", "fps", "name", "source", "license")


class ClipFormatError(ValueError):
    """A clip file or array that breaks the format; the message names the file and the problem."""


@dataclass(frozen=True)
class Clip:
    """qpos (T,76), qvel (T,75), obs (T,358) at `fps` frames per second, plus provenance."""

    qpos: np.ndarray
    qvel: np.ndarray
    obs: np.ndarray
    name: str
    source: str = "unknown"
    license: str = "unknown"
    fps: int = FPS

    def __post_init__(self) -> None:
        validate_arrays(self.qpos, self.qvel, self.obs, self.fps, where=f"clip {self.name!r}")

    @property
    def n_frames(self) -> int:
        return int(self.qpos.shape[0])

    @property
    def seconds(self) -> float:
        return self.n_frames / self.fps


def from_qpos(qpos: np.ndarray, name: str, source: str = "unknown", license: str = "unknown",
              fps: float = FPS) -> Clip:
    """Build a clip from a joint trajectory: resample to 30 Hz, then derive qvel and obs consistently."""
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe
    from motions.kinematics import finite_difference_qvel, resample_qpos

    model = load_model()
    qpos = np.asarray(qpos, dtype=np.float64)
    if fps != FPS:
        qpos = resample_qpos(qpos, fps, FPS)
    qvel = finite_difference_qvel(model, qpos, FPS)
    obs = observe(model, qpos, qvel)
    return Clip(qpos=qpos, qvel=qvel, obs=obs, name=name, source=source, license=license)


def validate_arrays(qpos: np.ndarray, qvel: np.ndarray, obs: np.ndarray, fps: int, where: str) -> None:
    """Raise ClipFormatError on wrong shapes, dtypes, non-finite values, fps or length."""
    checks = (("qpos", qpos, NQ), ("qvel", qvel, NV), ("obs", obs, OBS_DIM))
    for key, arr, width in checks:
        if not isinstance(arr, np.ndarray) or arr.dtype.kind != "f":
            raise ClipFormatError(f"{where}: {key} must be a floating-point array, got "
                                  f"{getattr(arr, 'dtype', type(arr))}")
        if arr.ndim != 2 or arr.shape[1] != width:
            raise ClipFormatError(f"{where}: {key} must have shape (T, {width}), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            bad = int(np.argwhere(~np.isfinite(arr))[0, 0])
            raise ClipFormatError(f"{where}: {key} has NaN or inf values (first at frame {bad})")
    lengths = {qpos.shape[0], qvel.shape[0], obs.shape[0]}
    if len(lengths) != 1:
        raise ClipFormatError(f"{where}: qpos, qvel and obs have different lengths {qpos.shape[0]}, {qvel.shape[0]}, "
                              f"{obs.shape[0]}")
    if qpos.shape[0] < MIN_FRAMES:
        raise ClipFormatError(f"{where}: clip has {qpos.shape[0]} frames, at least {MIN_FRAMES} are needed")
    if fps != FPS:
        raise ClipFormatError(f"{where}: fps must be {FPS}, got {fps}")
    if qpos.shape[0] > max_clip_frames():
        raise ClipFormatError(too_long(qpos.shape[0] / fps, where))
    speed = np.linalg.norm(np.diff(qpos[:, :3], axis=0), axis=1) * fps
    if np.any(speed > MAX_ROOT_SPEED):
        raise ClipFormatError(f"{where}: root moves {speed.max():.3g} m/s between frames {int(np.argmax(speed))} and "
                              f"{int(np.argmax(speed)) + 1}, faster than {MAX_ROOT_SPEED:g} m/s (a teleport?)")
    vel = np.linalg.norm(qvel[:, :3], axis=1)
    if np.any(vel > MAX_ROOT_SPEED):
        raise ClipFormatError(f"{where}: root velocity qvel[:, :3] reaches {vel.max():.3g} m/s at frame "
                              f"{int(np.argmax(vel))}, faster than {MAX_ROOT_SPEED:g} m/s")
    norms = np.linalg.norm(qpos[:, 3:7], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        raise ClipFormatError(f"{where}: root quaternion qpos[:, 3:7] is not unit length (norms "
                              f"{norms.min():.3f}..{norms.max():.3f})")


def save_clip(clip: Clip, path: str | os.PathLike) -> Path:
    """Write atomically (temp file + rename), so an interrupted save never leaves a half-written clip."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".npz.tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(
                fh,
                qpos=clip.qpos.astype(np.float64), qvel=clip.qvel.astype(np.float64), obs=clip.obs.astype(np.float32),
                fps=np.int64(clip.fps), name=np.str_(clip.name), source=np.str_(clip.source),
                license=np.str_(clip.license),
            )
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the clip normal file permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_clip(path: str | os.PathLike) -> Clip:
    """Load and validate a clip; never unpickles. Errors name the file and what is wrong."""
    path = Path(path)
    if not path.exists():
        raise ClipFormatError(f"{path}: no such clip file")
    try:
        arrays = read_npz(path, _KEYS, ClipFormatError, "clip archive", max_rows=max_clip_frames())
    except ClipFormatError as err:
        raise ClipFormatError(f"{err}{_import_hint(path)}") from None
    missing = [k for k in _KEYS if k not in arrays]
    if missing:
        raise ClipFormatError(f"{path}: missing keys {missing}{_import_hint(path)}")
    for key in ("name", "source", "license"):
        if arrays[key].ndim != 0 or arrays[key].dtype.kind != "U":
            raise ClipFormatError(f"{path}: {key} must be a string")
    fps = arrays["fps"]
    if fps.ndim != 0 or fps.dtype.kind not in "iu":
        raise ClipFormatError(f"{path}: fps must be an integer scalar")
    validate_arrays(arrays["qpos"], arrays["qvel"], arrays["obs"], int(fps), where=str(path))
    _check_obs_current(arrays["qpos"], arrays["qvel"], arrays["obs"], where=str(path))
    return Clip(
        qpos=arrays["qpos"].astype(np.float64), qvel=arrays["qvel"].astype(np.float64),
        obs=arrays["obs"].astype(np.float32), name=str(arrays["name"]), source=str(arrays["source"]),
        license=str(arrays["license"]), fps=int(fps),
    )


def _import_hint(path: Path) -> str:
    """A pointer to the importer when a file that is not a clip is a motion file the importers read."""
    from motions.formats import UnknownFormatError, detect_format

    try:
        fmt = detect_format(path)
        if fmt == "amass":
            with zipfile.ZipFile(path) as zf:
                if "poses.npy" not in zf.namelist():
                    return ""
    except (UnknownFormatError, zipfile.BadZipFile, OSError):
        return ""
    return f"; it is a {fmt} motion file: import it first with `fbcpr motions import`"


def _check_obs_current(qpos: np.ndarray, qvel: np.ndarray, obs: np.ndarray, where: str) -> None:
    """Recompute every frame's observation (batched, so cheap): a clip made by an older observation function, or
    with corrupted frames, must be re-imported, not silently fed to a model trained on the current one."""
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe

    diff = np.abs(observe(load_model(), qpos, qvel) - obs).max(axis=1)
    if diff.max() > 1e-3:
        raise ClipFormatError(
            f"{where}: obs do not match the humanoid's observation function (difference {diff.max():.3g}, first at "
            f"frame {int(np.argmax(diff > 1e-3))}); the clip was made by another version or is damaged: re-import it"
        )
