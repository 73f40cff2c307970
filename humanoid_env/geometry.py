"""Where the body is lowest: the one implementation behind grounding poses, init samplers and clip importers.

Placing a pose on the floor (goal poses, synthetic clips, dropped fall states, retargeted mocap) needs the lowest
world z of the body's collision geoms. It is exact for the spheres, capsules and boxes the humanoid is made of and
needs only forward kinematics, so it is cheaper than running collision detection against the floor.
"""
from __future__ import annotations

import mujoco
import numpy as np


def geom_bottoms(model: mujoco.MjModel, qpos: np.ndarray, data: mujoco.MjData | None = None) -> np.ndarray:
    """(..., ngeom) lowest world z of every body geom at each (..., nq) pose; world geoms (the floor) get +inf.

    `data` is scratch space for the kinematics (a fresh MjData when None); its state is overwritten.
    """
    qpos = np.asarray(qpos, dtype=np.float64)
    if qpos.shape[-1:] != (model.nq,):
        raise ValueError(f"geom_bottoms: qpos must end in nq={model.nq}, got shape {qpos.shape}")
    data = mujoco.MjData(model) if data is None else data
    flat = qpos.reshape(-1, model.nq)
    z = np.empty((len(flat), model.ngeom))
    zrow = np.empty((len(flat), model.ngeom, 3))  # world z component of each geom's local axes
    for t, q in enumerate(flat):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        z[t] = data.geom_xpos[:, 2]
        zrow[t] = data.geom_xmat.reshape(-1, 3, 3)[:, 2, :]
    size, gtype = model.geom_size, model.geom_type
    low = np.where(
        gtype == mujoco.mjtGeom.mjGEOM_BOX, z - np.abs(zrow * size).sum(-1),
        np.where(gtype == mujoco.mjtGeom.mjGEOM_CAPSULE, z - np.abs(zrow[..., 2]) * size[:, 1] - size[:, 0],
                 z - size[:, 0]),  # sphere
    )
    low[:, model.geom_bodyid == 0] = np.inf
    return low.reshape(qpos.shape[:-1] + (model.ngeom,))


def lowest_point(model: mujoco.MjModel, qpos: np.ndarray, data: mujoco.MjData | None = None) -> np.ndarray:
    """(...) lowest world z of the body at each (..., nq) pose: subtract it from qpos[..., 2] to stand on z = 0."""
    return geom_bottoms(model, qpos, data).min(axis=-1)
