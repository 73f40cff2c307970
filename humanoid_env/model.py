"""The SMPL humanoid's MuJoCo model and the names that other modules index by."""
from __future__ import annotations

from functools import lru_cache
from importlib import resources

import mujoco
import numpy as np

#: Body names in MuJoCo order (depth first); index 0 is the root.
BODY_NAMES: tuple[str, ...] = (
    "Pelvis",
    "L_Hip", "L_Knee", "L_Ankle", "L_Toe",
    "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
    "Torso", "Spine", "Chest", "Neck", "Head",
    "L_Thorax", "L_Shoulder", "L_Elbow", "L_Wrist", "L_Hand",
    "R_Thorax", "R_Shoulder", "R_Elbow", "R_Wrist", "R_Hand",
)
#: Hinge joint names, three per non-root body, in qpos order after the 7 free-joint values.
JOINT_NAMES: tuple[str, ...] = tuple(f"{b}_{ax}" for b in BODY_NAMES[1:] for ax in "xyz")

NQ, NV, NU = 76, 75, 69
CONTROL_HZ = 30
SIM_HZ = 450
N_SUBSTEPS = SIM_HZ // CONTROL_HZ


def model_path() -> str:
    """Path of the shipped MJCF, for tools that want to load it themselves."""
    return str(resources.files("humanoid_env") / "assets" / "smpl_humanoid.xml")


@lru_cache(maxsize=1)
def _cached_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(model_path())


def load_model() -> mujoco.MjModel:
    """A fresh copy of the humanoid model (callers may change options without affecting others)."""
    return _copy_model(_cached_model())


def _copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
    import copy

    return copy.copy(model)


def joint_ranges(model: mujoco.MjModel | None = None) -> np.ndarray:
    """(69, 2) hinge limits in radians, in qpos order."""
    m = model if model is not None else _cached_model()
    return np.asarray(m.jnt_range[1:], dtype=np.float64).copy()


def default_qpos(model: mujoco.MjModel | None = None) -> np.ndarray:
    """Standing T-pose: all joint angles 0, root at its rest height."""
    m = model if model is not None else _cached_model()
    return np.asarray(m.qpos0, dtype=np.float64).copy()
