"""Named goal poses for goal-reaching evaluation (App. C.3.3), and goals taken from motion clips.

Each pose is a joint-angle spec on our model (degrees; unspecified joints are 0, i.e. the T-pose) plus a root
orientation (roll, pitch, yaw in degrees). The root height is solved so that the lowest geom touches the floor.
Every pose is checked to hold under PD control from its own state (tests/test_goals.py, `hold_drift`).
A goal is a full state with zero velocities; `goal_obs` is its observation.
"""
from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import mujoco
import numpy as np

from humanoid_env.geometry import lowest_point
from humanoid_env.model import JOINT_NAMES, N_SUBSTEPS, NV, load_model
from humanoid_env.observation import observe

_JOINT_INDEX = {name: 7 + i for i, name in enumerate(JOINT_NAMES)}


@dataclass(frozen=True)
class GoalPose:
    """Joint angles in degrees (name -> value) and the root's roll/pitch/yaw in degrees. With `balance`, the whole
    body is pitched about the ankles (root pitch plus an equal ankle correction, feet kept flat) until the
    centre of mass lies `com_ahead` m in front of the ankle joints, so a statue-like PD hold does not topple."""

    joints: dict[str, float] = field(default_factory=dict)
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    balance: bool = False
    com_ahead: float = 0.0


def _merge(*parts: Mapping[str, float]) -> dict[str, float]:
    out: dict[str, float] = {}
    for p in parts:
        out.update(p)
    return out


# Reusable limb settings (degrees). Left arm: x>0 raises it, z<0 swings it forward, y twists it so that elbow z
# bends the forearm up (y<0) or down (y>0). The right arm mirrors: x and z angles change sign, y angles do not.
ARMS_DOWN: dict[str, float] = {"L_Shoulder_x": -75, "R_Shoulder_x": 75}
ARMS_LOW45: dict[str, float] = {"L_Shoulder_x": -45, "R_Shoulder_x": 45}
ARMS_UP: dict[str, float] = {"L_Shoulder_x": 85, "R_Shoulder_x": -85}
ARMS_FORWARD: dict[str, float] = {"L_Shoulder_z": -90, "R_Shoulder_z": 90}
ARMS_REACH: dict[str, float] = {"L_Shoulder_x": -45, "R_Shoulder_x": 45, "L_Shoulder_z": -60, "R_Shoulder_z": 60}
L_FOREARM_UP: dict[str, float] = {"L_Shoulder_y": -90, "L_Elbow_z": -90}
R_FOREARM_UP: dict[str, float] = {"R_Shoulder_y": -90, "R_Elbow_z": 90}


def _squat(thigh: float, shank: float, lean: float) -> dict[str, float]:
    """Both legs: thigh `thigh` deg forward of vertical, shank `shank` deg behind vertical, feet flat, for a
    pelvis pitched forward by `lean`."""
    leg = {"Hip_y": -thigh - lean, "Knee_y": thigh + shank, "Ankle_y": -shank}
    return {f"{s}_{k}": v for s in "LR" for k, v in leg.items()}


def Stand(joints: dict[str, float] | None = None, **kw: Any) -> GoalPose:
    """A pose on the feet, balanced over the ankles."""
    return GoalPose(joints or {}, balance=True, **kw)


GOALS: dict[str, GoalPose] = {
    # standing, arm variations
    "t_pose": Stand(),
    "t_pose_lower_arms": Stand(ARMS_LOW45),
    "t_pose_bow_head": Stand({"Neck_y": 35, "Head_y": 25}),
    "a_pose": Stand(ARMS_DOWN),
    "zombie": Stand(ARMS_FORWARD),
    "arms_stretch": Stand(ARMS_UP),
    "left_arm_up": Stand({"L_Shoulder_x": 85, "R_Shoulder_x": 75}),
    "right_arm_up": Stand({"L_Shoulder_x": -75, "R_Shoulder_x": -85}),
    "right_hand_wave": Stand(_merge({"L_Shoulder_x": -75}, R_FOREARM_UP)),
    "left_hand_wave": Stand(_merge({"R_Shoulder_x": 75}, L_FOREARM_UP)),
    "hands_up": Stand(_merge(L_FOREARM_UP, R_FOREARM_UP)),
    "egyptian": Stand(_merge(L_FOREARM_UP, {"R_Shoulder_y": 90, "R_Elbow_z": 90})),  # left forearm up, right down
    "scratching_head": Stand({"L_Shoulder_x": -75, "R_Shoulder_x": -50, "R_Shoulder_y": -90, "R_Shoulder_z": 15,
                              "R_Elbow_z": 90}),
    "point_forward": Stand({"L_Shoulder_x": -75, "R_Shoulder_z": 90}),
    "arms_forward_down": Stand({"L_Shoulder_x": -45, "R_Shoulder_x": 45, "L_Shoulder_z": -90, "R_Shoulder_z": 90}),
    "hands_on_hips": Stand({"L_Shoulder_x": -30, "L_Elbow_y": 80, "L_Elbow_z": -90,
                            "R_Shoulder_x": 30, "R_Elbow_y": 80, "R_Elbow_z": 90}),
    # standing, trunk and leg variations
    "bow": Stand(_merge(ARMS_DOWN, {"Torso_y": 15, "Spine_y": 15, "Chest_y": 15}), com_ahead=-0.02),
    "side_bend_left": Stand({"L_Shoulder_x": -65, "R_Shoulder_x": 75, "Torso_x": -10, "Spine_x": -10, "Chest_x": -10}),
    "twist_left": Stand(_merge(ARMS_DOWN, {"Torso_z": 20, "Spine_z": 20, "Chest_z": 20})),
    "wide_stance": Stand(_merge(ARMS_DOWN, {"L_Hip_x": 15, "R_Hip_x": -15, "L_Ankle_x": -15, "R_Ankle_x": 15})),
    "look_up": Stand(_merge(ARMS_DOWN, {"Neck_y": -30, "Head_y": -20})),
    # crouches and kneels
    "crouch_high": Stand(_merge(ARMS_FORWARD, _squat(45, 20, 15)), pitch=15),
    "crouch_medium": Stand(_merge(ARMS_FORWARD, _squat(65, 25, 25)), pitch=25),
    "crouch_low": Stand(_merge(ARMS_FORWARD, _squat(85, 30, 40)), pitch=40, com_ahead=0.06),
    "kneel_left": GoalPose(_merge(ARMS_DOWN, {"L_Hip_y": 0, "L_Knee_y": 90, "L_Ankle_y": 55,
                                              "R_Hip_y": -80, "R_Knee_y": 105, "R_Ankle_y": -15}), pitch=-10),
    "kneel_right": GoalPose(_merge(ARMS_DOWN, {"R_Hip_y": 0, "R_Knee_y": 90, "R_Ankle_y": 55,
                                               "L_Hip_y": -80, "L_Knee_y": 105, "L_Ankle_y": -15}), pitch=-10),
    "kneel_both": GoalPose(_merge(ARMS_DOWN, {"L_Knee_y": 90, "R_Knee_y": 90, "L_Ankle_y": 50, "R_Ankle_y": 50})),
    # sitting and lying on the floor
    "sit_on_ground": GoalPose(_merge(ARMS_REACH, {"L_Hip_y": -95, "R_Hip_y": -95, "Torso_y": 20, "Spine_y": 20,
                                                  "Chest_y": 10})),
    "sit_straddle": GoalPose(_merge(ARMS_FORWARD, {"L_Hip_y": -70, "R_Hip_y": -70, "L_Hip_x": 40, "R_Hip_x": -40,
                                                   "Torso_y": 20, "Spine_y": 20, "Chest_y": 10}), pitch=-20),
    "lie_back": GoalPose(ARMS_LOW45, pitch=-90),
    "lie_back_arms_up": GoalPose(ARMS_UP, pitch=-90),
    "lie_front": GoalPose(_merge(ARMS_LOW45, {"L_Ankle_y": 55, "R_Ankle_y": 55}), pitch=88),
    "lie_back_knees_up": GoalPose(_merge(ARMS_LOW45, {"L_Hip_y": -60, "R_Hip_y": -60, "L_Knee_y": 110,
                                                      "R_Knee_y": 110, "L_Ankle_y": 40, "R_Ankle_y": 40}), pitch=-90),
}
#: Largest d_smpl drift from a goal allowed while plain PD targets (ctrl = the goal's joint angles) hold it for
#: 2 s. It absorbs the steady sag of a PD controller under gravity and stays well inside the goal radius (2).
HOLD_TOLERANCE = 1.2


def goal_names() -> list[str]:
    return list(GOALS)


def _root_quat(pose: GoalPose) -> np.ndarray:
    quat = np.array([1.0, 0.0, 0.0, 0.0])
    for axis, deg in (((0, 0, 1), pose.yaw), ((0, 1, 0), pose.pitch), ((1, 0, 0), pose.roll)):
        q = np.empty(4)
        mujoco.mju_axisAngle2Quat(q, np.asarray(axis, dtype=np.float64), np.deg2rad(deg))
        mujoco.mju_mulQuat(quat, quat.copy(), q)
    return quat


def pose_qpos(pose: GoalPose, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(76,) qpos of a spec: joint angles (clipped to the joint ranges), root orientation, feet on the floor."""
    m = model if model is not None else load_model()
    qpos = m.qpos0.copy()
    for name, deg in pose.joints.items():
        if name not in _JOINT_INDEX:
            raise ValueError(f"goal pose: unknown joint {name!r}; joints are named like 'L_Knee_y'")
        qpos[_JOINT_INDEX[name]] = np.deg2rad(deg)
    qpos[7:] = np.clip(qpos[7:], m.jnt_range[1:, 0], m.jnt_range[1:, 1])
    qpos[:2] = 0.0
    qpos[2] = 2.0
    qpos[3:7] = _root_quat(pose)
    if pose.balance:
        qpos = _balance(m, qpos, pose)
    qpos[2] -= lowest_point(m, qpos)
    return qpos


_ANKLE_Y = [_JOINT_INDEX["L_Ankle_y"], _JOINT_INDEX["R_Ankle_y"]]


def _balance(m: mujoco.MjModel, qpos: np.ndarray, pose: GoalPose) -> np.ndarray:
    """Pitch the body about the ankles (root pitch -d, ankles +d) until the COM is `com_ahead` in front of them."""
    data = mujoco.MjData(m)
    ankles = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("L_Ankle", "R_Ankle")]
    delta = 0.0
    q = qpos.copy()
    for _ in range(5):
        q = qpos.copy()
        q[3:7] = _root_quat(GoalPose(roll=pose.roll, pitch=pose.pitch - np.rad2deg(delta), yaw=pose.yaw))
        q[_ANKLE_Y] = qpos[_ANKLE_Y] + delta
        data.qpos[:] = q
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        ankle = data.xpos[ankles].mean(axis=0)
        com = data.subtree_com[1]
        delta += np.arctan2(com[0] - ankle[0] - pose.com_ahead, com[2] - ankle[2])
    lo, hi = m.jnt_range[1:, 0], m.jnt_range[1:, 1]
    q[7:] = np.clip(q[7:], lo, hi)
    return q


def _lookup(name: str) -> GoalPose:
    if name not in GOALS:
        close = difflib.get_close_matches(name, list(GOALS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown goal {name!r}{hint}; known goals: {', '.join(GOALS)}")
    return GOALS[name]


@cache
def _goal_qpos_cached(name: str) -> np.ndarray:
    q = pose_qpos(_lookup(name))
    q.setflags(write=False)
    return q


def goal_qpos(name: str) -> np.ndarray:
    """(76,) qpos of a named goal pose."""
    return _goal_qpos_cached(name).copy()


def goal_obs(name: str) -> np.ndarray:
    """(358,) observation of a named goal pose with zero velocities."""
    return observe(load_model(), goal_qpos(name), np.zeros(NV))


def goal_from_clip(clip: Any, frame: int) -> np.ndarray:
    """(358,) goal observation from any frame of a clip (anything with a (T,76) `qpos`), velocities zeroed."""
    qpos = np.asarray(getattr(clip, "qpos", None) if not isinstance(clip, np.ndarray) else clip)
    if qpos.ndim != 2 or qpos.shape[1] != 76:
        raise ValueError(f"goal_from_clip: expected a clip with qpos of shape (T, 76), got {qpos.shape}")
    if not -qpos.shape[0] <= frame < qpos.shape[0]:
        raise ValueError(f"goal_from_clip: frame {frame} out of range for a clip of {qpos.shape[0]} frames")
    return observe(load_model(), qpos[frame], np.zeros(NV))


def hold_drift(qpos: np.ndarray, seconds: float = 2.0, model: mujoco.MjModel | None = None) -> np.ndarray:
    """d_smpl to the starting pose at each control step while PD control holds the pose's joint angles
    (ctrl = joint targets) from rest. A stable goal keeps these small."""
    m = model if model is not None else load_model()
    data = mujoco.MjData(m)
    data.qpos[:] = qpos
    data.ctrl[:] = np.clip(qpos[7:], m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
    target = observe(m, qpos, np.zeros(NV))[:214]
    steps = int(round(seconds * 30))
    poses = np.empty((steps, 214))
    for t in range(steps):
        mujoco.mj_step(m, data, nstep=N_SUBSTEPS)
        poses[t] = observe(m, data.qpos, np.zeros(NV))[:214]
    return np.linalg.norm(poses - target, axis=1)
