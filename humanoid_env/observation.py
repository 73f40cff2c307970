"""The one observation function: 358 float32 values in the heading frame, from (qpos, qvel) by kinematics.

Layout (all in the heading frame: root yaw removed, origin at the root):
  root height (1) | positions of the 23 non-root bodies relative to the root (69)
  | orientations of all 24 bodies as 6-D tangent-normal vectors (144)
  | linear velocities of the 24 bodies (72) | angular velocities of the 24 bodies (72).
The first 214 values are the pose part used by tracking and goal distances.
"""
from __future__ import annotations

import mujoco
import numpy as np

N_BODIES = 24
OBS_DIM = 358

ROOT_HEIGHT = slice(0, 1)
BODY_POS = slice(1, 70)
BODY_ROT = slice(70, 214)
BODY_LINVEL = slice(214, 286)
BODY_ANGVEL = slice(286, 358)
POSE = slice(0, 214)

#: Named slices of the observation vector, for users and for reward code.
LAYOUT: dict[str, slice] = {
    "root_height": ROOT_HEIGHT,
    "body_pos": BODY_POS,
    "body_rot": BODY_ROT,
    "body_linvel": BODY_LINVEL,
    "body_angvel": BODY_ANGVEL,
    "pose": POSE,
}


def heading_rotation(root_xmat: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations about z by the root's heading.

    The heading is the horizontal part of the pelvis forward axis x plus 0.5*|x_z| times that of its up axis z.
    With x alone the heading is undefined when lying flat (x vertical), exactly where the lying goals and
    rewards live; the z term takes over there (the heading then points along the body, towards the head),
    and vanishes when the pelvis is level, so any roll leaves a standing heading alone. No yaw-equivariant
    heading is continuous everywhere: this one jumps only with the pelvis pitched ~65 deg back or ~115 deg
    forward, poses passed through rather than held.
    """
    fwd, up = root_xmat[..., :, 0], root_xmat[..., :, 2]
    weight = 0.5 * np.abs(fwd[..., 2])
    hx = fwd[..., 0] + weight * up[..., 0]
    hy = fwd[..., 1] + weight * up[..., 1]
    yaw = np.arctan2(hy, hx)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros(yaw.shape + (3, 3))
    rot[..., 0, 0], rot[..., 0, 1] = c, -s
    rot[..., 1, 0], rot[..., 1, 1] = s, c
    rot[..., 2, 2] = 1.0
    return rot


def assemble(xpos: np.ndarray, xmat: np.ndarray, cvel: np.ndarray, com: np.ndarray) -> np.ndarray:
    """Observation from world-frame body kinematics, vectorized over a leading batch axis.

    xpos (N,24,3), xmat (N,24,3,3), cvel (N,24,6) as MuJoCo's [angular, linear at com],
    com (N,3) the root subtree's centre of mass (the point cvel's linear part refers to).
    All 119 world vectors (23 positions, 48 tangent/normal axes, 24 + 24 velocities) are stacked in
    observation order and turned into the heading frame by one batched matmul: the env calls this every
    step, so it keeps to a few large numpy operations.
    """
    n = xpos.shape[0]
    vec = np.empty((n, 119, 3))
    np.subtract(xpos[:, 1:], xpos[:, :1], out=vec[:, :23])
    vec[:, 23:71].reshape(n, N_BODIES, 2, 3)[:] = np.swapaxes(xmat[..., ::2], -1, -2)  # x and z axes
    ang, r = cvel[..., :3], xpos - com[:, None, :]
    lin = vec[:, 71:95]
    # linear velocity at each body origin: v_com + w x r
    np.multiply(ang[..., 1], r[..., 2], out=lin[..., 0])
    lin[..., 0] -= ang[..., 2] * r[..., 1]
    np.multiply(ang[..., 2], r[..., 0], out=lin[..., 1])
    lin[..., 1] -= ang[..., 0] * r[..., 2]
    np.multiply(ang[..., 0], r[..., 1], out=lin[..., 2])
    lin[..., 2] -= ang[..., 1] * r[..., 0]
    lin += cvel[..., 3:]
    vec[:, 95:] = ang
    out = np.empty((n, OBS_DIM), np.float32)
    out[:, 0] = xpos[:, 0, 2]
    out[:, 1:] = np.matmul(vec, heading_rotation(xmat[:, 0])).reshape(n, OBS_DIM - 1)  # v @ R = R^T v: world -> heading
    return out


def kinematic_passes(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """The passes that fill what `assemble` reads (body poses, com frames, com velocities) from (qpos, qvel)."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    mujoco.mj_comVel(model, data)


def read_kinematics(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, ...]:
    """Run the kinematic passes on data's (qpos, qvel) and copy what `assemble` needs."""
    kinematic_passes(model, data)
    return (data.xpos[1:].copy(), data.xmat[1:].reshape(-1, 3, 3).copy(), data.cvel[1:].copy(),
            data.subtree_com[1].copy())


def observe(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, data: mujoco.MjData | None = None) -> np.ndarray:
    """Observation(s) for states (qpos (...,76), qvel (...,75)); returns (..., 358) float32.

    Uses kinematics only (no dynamics, no contacts), so it serves the env, motion clips and goals alike.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    qvel = np.asarray(qvel, dtype=np.float64)
    if qpos.shape[-1] != model.nq or qvel.shape[-1] != model.nv or qpos.shape[:-1] != qvel.shape[:-1]:
        raise ValueError(
            f"observe: expected qpos (..., {model.nq}) and qvel (..., {model.nv}) with matching batch shape, "
            f"got {qpos.shape} and {qvel.shape}"
        )
    batch = qpos.shape[:-1]
    qp, qv = qpos.reshape(-1, model.nq), qvel.reshape(-1, model.nv)
    n = qp.shape[0]
    d = data if data is not None else mujoco.MjData(model)
    xpos = np.empty((n, N_BODIES, 3))
    xmat = np.empty((n, N_BODIES, 9))
    cvel = np.empty((n, N_BODIES, 6))
    com = np.empty((n, 3))
    for i in range(n):  # written straight into the batch arrays: rebuilding a 50k-state reward sample is this loop
        d.qpos[:] = qp[i]
        d.qvel[:] = qv[i]
        kinematic_passes(model, d)
        xpos[i], xmat[i], cvel[i], com[i] = d.xpos[1:], d.xmat[1:], d.cvel[1:], d.subtree_com[1]
    return assemble(xpos, xmat.reshape(n, N_BODIES, 3, 3), cvel, com).reshape(batch + (OBS_DIM,))
