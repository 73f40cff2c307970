"""Trajectory math on qpos sequences: MuJoCo-consistent velocities, resampling to 30 Hz, looping."""
from __future__ import annotations

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from humanoid_env.geometry import geom_bottoms as geom_bottoms  # re-exported for the importers and their tests
from humanoid_env.geometry import lowest_point


def finite_difference_qvel(model: mujoco.MjModel, qpos: np.ndarray, fps: float) -> np.ndarray:
    """(T,nv) velocities by central differences of (T,nq) positions.

    mj_differentiatePos follows MuJoCo's qvel convention for the free joint (linear velocity in the world
    frame, angular velocity in the body's local frame), so the result can be fed to the simulator as is.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    n = qpos.shape[0]
    qvel = np.zeros((n, model.nv))
    if n < 2:
        return qvel
    dt = 1.0 / fps
    lo = np.r_[0, np.arange(0, n - 2), n - 2]
    hi = np.r_[1, np.arange(2, n), n - 1]
    buf = np.zeros(model.nv)
    for t in range(n):
        span = (hi[t] - lo[t]) * dt
        mujoco.mj_differentiatePos(model, buf, span, qpos[lo[t]], qpos[hi[t]])
        qvel[t] = buf
    return qvel


def target_times(n_src: int, fps_src: float, fps_dst: float) -> np.ndarray:
    """Sample times (in source frames) of a resampling that covers the source span at fps_dst."""
    duration = (n_src - 1) / fps_src
    n_dst = int(np.floor(duration * fps_dst + 1e-6)) + 1
    return np.arange(n_dst) * (fps_src / fps_dst)


def interp_linear(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Linear interpolation of (T, ...) values at fractional frame indices."""
    i0 = np.clip(np.floor(times).astype(int), 0, values.shape[0] - 1)
    i1 = np.minimum(i0 + 1, values.shape[0] - 1)
    w = (times - i0).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1 - w) * values[i0] + w * values[i1]


def interp_rotations(quat_wxyz: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Slerp of (T, ..., 4) wxyz quaternions at fractional frame indices; returns (len(times), ..., 4)."""
    lead = quat_wxyz.shape[1:-1]
    q = quat_wxyz.reshape(quat_wxyz.shape[0], -1, 4)
    out = np.empty((len(times), q.shape[1], 4))
    key_times = np.arange(q.shape[0], dtype=np.float64)
    clipped = np.clip(times, 0, q.shape[0] - 1)
    for j in range(q.shape[1]):
        rot = Rotation.from_quat(q[:, j], scalar_first=True)
        out[:, j] = Slerp(key_times, rot)(clipped).as_quat(scalar_first=True)
    return out.reshape((len(times),) + lead + (4,))


def resample_qpos(qpos: np.ndarray, fps_src: float, fps_dst: float) -> np.ndarray:
    """Resample a (T,76) trajectory: slerp for the root quaternion, linear for positions and hinge angles."""
    times = target_times(qpos.shape[0], fps_src, fps_dst)
    out = interp_linear(qpos, times)
    out[:, 3:7] = interp_rotations(qpos[:, 3:7], times)
    return out


def _yaw(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.moveaxis(quat_wxyz, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def repeat_loop(qpos: np.ndarray, cycles: int) -> np.ndarray:
    """Repeat a cyclic clip whose last frame closes the cycle, accumulating the root's planar offset and yaw.

    Each new cycle is the previous one moved by the planar transform from the first to the last frame, so a
    walk keeps walking forward instead of jumping back to the start. The duplicate closing frame is dropped.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    if cycles < 1:
        raise ValueError(f"repeat_loop: cycles must be >= 1, got {cycles}")
    yaw0, yaw1 = _yaw(qpos[0, 3:7]), _yaw(qpos[-1, 3:7])
    dyaw = yaw1 - yaw0
    c, s = np.cos(dyaw), np.sin(dyaw)
    rot = np.array([[c, -s], [s, c]])
    # G(p) = rot @ (p - p0) + p1 maps the first frame onto the last; cycle k+1 = G(cycle k)
    p0, p1 = qpos[0, :2].copy(), qpos[-1, :2].copy()
    dquat = Rotation.from_euler("z", dyaw)
    parts, cur = [qpos], qpos
    for _ in range(cycles - 1):
        nxt = cur.copy()
        nxt[:, :2] = (nxt[:, :2] - p0) @ rot.T + p1
        nxt[:, 3:7] = (dquat * Rotation.from_quat(nxt[:, 3:7], scalar_first=True)).as_quat(scalar_first=True)
        parts.append(nxt[1:])
        cur = nxt
    return np.concatenate(parts)


def foot_geom_ids(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids of the four foot segments (ankle and toe boxes of both feet)."""
    names = ("L_Ankle", "L_Toe", "R_Ankle", "R_Toe")
    return np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names])


def put_on_floor(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Shift the root height per frame so the lowest body point touches z = 0 (for grounded synthetic clips)."""
    qpos = np.array(qpos, dtype=np.float64)
    qpos[:, 2] -= lowest_point(model, qpos)
    return qpos
