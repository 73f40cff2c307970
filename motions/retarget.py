"""Keypoint retargeting onto our humanoid with mink inverse kinematics, shared by the DeepMimic and BVH importers.

A source supplies world positions of a few named keypoints (z up, any units, any heading) and, where its rest
frames match ours, world orientations of some segments. We rebuild the targets with *our* segment lengths along the
source's segment directions ("scale to our body size"), solve a few warm-started IK iterations per 30 Hz frame,
clip to our joint ranges, and finally move the root vertically so feet in contact sit on the floor.
"""
from __future__ import annotations

import ctypes
import glob
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import mink
import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from humanoid_env.model import JOINT_NAMES, joint_ranges, load_model
from motions.kinematics import foot_geom_ids, geom_bottoms, interp_linear, interp_rotations

KEYPOINTS = (
    "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle", "l_toe", "r_toe",
    "neck", "head", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist",
)
#: Segments whose world orientation a source may give, expressed so identity = our rest frame of that body.
ORIENTED = {"pelvis": "Pelvis", "chest": "Chest", "head": "Head", "l_foot": "L_Ankle", "r_foot": "R_Ankle"}

#: (body, position cost, orientation cost) of the IK tasks.
_TASKS = (
    ("Pelvis", 10.0, 5.0), ("L_Knee", 3.0, 0.0), ("R_Knee", 3.0, 0.0), ("L_Ankle", 10.0, 1.0),
    ("R_Ankle", 10.0, 1.0), ("L_Toe", 5.0, 0.0), ("R_Toe", 5.0, 0.0), ("Chest", 0.0, 2.0), ("Neck", 1.0, 0.0),
    ("Head", 0.5, 0.5), ("L_Shoulder", 1.0, 0.0), ("R_Shoulder", 1.0, 0.0), ("L_Elbow", 2.0, 0.0),
    ("R_Elbow", 2.0, 0.0), ("L_Wrist", 2.0, 0.0), ("R_Wrist", 2.0, 0.0),
)
CONTACT_HEIGHT = 0.03  # m, sole above the floor
CONTACT_SPEED = 0.5  # m/s
PLANT_TOL = 0.01  # m: contact feet farther from the floor, or other bodies deeper in it, get a planting IK pass
PLANT_ITERATIONS = 8
PLANT_ROUNDS = 3
PLANT_MARGIN = 0.005
PLANT_HOLD = 0.3
PLANT_HOLD_LEGS = 0.02


@contextmanager
def single_threaded_blas():
    """Run numpy's OpenBLAS on one thread inside the block.

    IK builds many tiny (75 x 75) matrix products; with a multi-threaded BLAS on a busy machine they spend most of
    their time synchronising threads (4x slower measured on 2 shared cores). No-op if the library is not found.
    """
    setter = getter = None
    for lib_path in glob.glob(os.path.join(os.path.dirname(np.__file__) + ".libs", "libscipy_openblas*.so*")):
        try:
            lib = ctypes.CDLL(lib_path)
            setter, getter = lib.scipy_openblas_set_num_threads64_, lib.scipy_openblas_get_num_threads64_
        except (OSError, AttributeError):
            continue
        break
    if setter is None:
        yield
        return
    before = getter()
    setter(1)
    try:
        yield
    finally:
        setter(before)


@dataclass
class SourceMotion:
    """Keypoint trajectories of one source clip, already converted to z up (units are rescaled later)."""

    name: str
    positions: dict[str, np.ndarray]  # keypoint -> (T, 3)
    times: np.ndarray  # (T,) seconds
    orientations: dict[str, np.ndarray] = field(default_factory=dict)  # ORIENTED key -> (T, 4) wxyz
    loop: bool = False
    floor: float | None = None  # source floor height (in source units); None: found from the feet (`source_floor`)
    soles: dict[str, np.ndarray] = field(default_factory=dict)  # "l"/"r" -> (T, k, 3) sole points for contacts
    source: str = "unknown"
    license: str = "unknown"

    def __post_init__(self) -> None:
        missing = [k for k in KEYPOINTS if k not in self.positions]
        if missing:
            raise ValueError(f"{self.name}: source lacks keypoints {missing}")
        n = len(self.times)
        if n < 2:
            raise ValueError(f"{self.name}: needs at least 2 frames, got {n}")
        if np.any(np.diff(self.times) <= 0):
            raise ValueError(f"{self.name}: frame times must increase")
        for key, arr in list(self.positions.items()) + list(self.orientations.items()):
            if arr.shape[0] != n or not np.all(np.isfinite(arr)):
                raise ValueError(f"{self.name}: {key} has shape {arr.shape} or non-finite values (expected {n} frames)")


#: Bounds past which a clip is flagged in the import report: foot slide (m/s over contact frames), penetration and
#: contact gap (m), joint limits (clipped joint-frames per frame), glitch (the fastest keypoint relative to the
#: pelvis, leg lengths/s: ballet spins reach 30 in the CMU takes, marker swaps 35-60), few contacts (share of
#: frames with a foot in contact, below which the slide and the gap say little).
QUALITY_LIMITS = {"foot slide": 0.3, "penetration": 0.02, "contact gap": 0.03, "joint limits": 0.05,
                  "glitch": 35.0, "few contacts": 0.2}


@dataclass
class RetargetReport:
    """What happened to one clip, for the import summary and tests."""

    name: str
    frames: int
    seconds: float
    compute_seconds: float = 0.0
    clipped: dict[str, int] = field(default_factory=dict)  # joint -> number of frames clipped to range
    max_penetration: float = 0.0  # m, deepest foot point below the floor
    max_contact_gap: float = 0.0  # m, largest |foot height| over contact frames
    keypoint_error: float = 0.0  # m, mean distance between IK result and targets
    foot_slide: float = 0.0  # m/s, mean horizontal speed of a foot over the frames it is in contact
    contacts: np.ndarray | None = None  # (T, 2) bool, left/right foot in contact (from the source)
    contact_share: float = 0.0  # share of frames with a foot in contact: a slide of 0 over no contact says nothing
    at_limits: dict[str, int] = field(default_factory=dict)  # joint -> frames it sits at a bound of its range
    peak_limb_speed: float = 0.0  # leg lengths/s, fastest keypoint relative to the pelvis in the source

    @property
    def clipped_total(self) -> int:
        return int(sum(self.clipped.values()))

    def flags(self) -> list[str]:
        """What in this clip is worth a look before training on it (QUALITY_LIMITS); empty for a clean clip."""
        measured = {"foot slide": self.foot_slide, "penetration": self.max_penetration,
                    "contact gap": self.max_contact_gap, "joint limits": self.clipped_total / max(self.frames, 1),
                    "glitch": self.peak_limb_speed}
        out = [name for name, value in measured.items() if value > QUALITY_LIMITS[name]]
        if self.contact_share < QUALITY_LIMITS["few contacts"]:
            out.append("few contacts")
        return out


class _Rest:
    """Offsets of our rest pose (all joint rotations identity, so body_pos is the rest offset in world)."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        self.xpos = {model.body(i).name: data.xpos[i].copy() for i in range(1, model.nbody)}
        pelvis = self.xpos["Pelvis"]
        self.hip_mid = 0.5 * (self.xpos["L_Hip"] + self.xpos["R_Hip"]) - pelvis  # in the pelvis frame

    def length(self, a: str, b: str) -> float:
        return float(np.linalg.norm(self.xpos[b] - self.xpos[a]))

    def offset(self, a: str, b: str) -> np.ndarray:
        return self.xpos[b] - self.xpos[a]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def _rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(T,3,3) smallest rotations taking unit vectors u onto unit vectors v (Rodrigues)."""
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=-1)
    c = np.einsum("ti,ti->t", u, v)
    k = axis / np.maximum(s, 1e-12)[:, None]
    kx = np.zeros(u.shape[:1] + (3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx -= np.swapaxes(kx, 1, 2)
    return np.eye(3) + s[:, None, None] * kx + (1 - c)[:, None, None] * (kx @ kx)


def _frame_from_axes(left: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(T,3,3) rotation with y along `left` and z as close as possible to `up` (x = forward)."""
    y = _unit(left)
    x = _unit(np.cross(y, up))
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=-1)


def _resample(src: SourceMotion, fps: float) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    frame_idx = np.interp(np.arange(0, src.times[-1] - src.times[0] + 1e-9, 1.0 / fps) + src.times[0],
                          src.times, np.arange(len(src.times)))
    pos = {k: interp_linear(v, frame_idx) for k, v in src.positions.items()}
    rot = {k: interp_rotations(v, frame_idx) for k, v in src.orientations.items()}
    for side in "lr":
        pts = src.soles.get(side)
        if pts is None:
            pts = np.stack([src.positions[f"{side}_ankle"], src.positions[f"{side}_toe"]], axis=1)
        pos[f"{side}_sole"] = interp_linear(pts, frame_idx)
    return pos, rot, frame_idx


def build_targets(src_pos: dict[str, np.ndarray], src_rot: dict[str, np.ndarray],
                  rest: _Rest) -> tuple[dict, dict, float]:
    """World targets for our bodies: our segment lengths along the source's segment directions.

    Returns (positions body -> (T,3), orientations body -> (T,3,3), scale applied to the source).
    """
    leg_src = np.median(
        np.linalg.norm(src_pos["l_knee"] - src_pos["l_hip"], axis=1)
        + np.linalg.norm(src_pos["l_ankle"] - src_pos["l_knee"], axis=1)
        + np.linalg.norm(src_pos["r_knee"] - src_pos["r_hip"], axis=1)
        + np.linalg.norm(src_pos["r_ankle"] - src_pos["r_knee"], axis=1)
    ) / 2
    leg_ours = rest.length("L_Hip", "L_Knee") + rest.length("L_Knee", "L_Ankle")
    scale = leg_ours / leg_src
    p = {k: v * scale for k, v in src_pos.items()}
    rots = {ORIENTED[k]: Rotation.from_quat(v, scalar_first=True).as_matrix() for k, v in src_rot.items()}
    hip_mid = 0.5 * (p["l_hip"] + p["r_hip"])
    if "Pelvis" not in rots:
        rots["Pelvis"] = _frame_from_axes(p["l_hip"] - p["r_hip"], p["neck"] - hip_mid)
    if "Chest" not in rots:
        rots["Chest"] = _frame_from_axes(p["l_shoulder"] - p["r_shoulder"], p["neck"] - hip_mid)
    r_pelvis = rots["Pelvis"]
    tgt: dict[str, np.ndarray] = {}
    tgt["Pelvis"] = hip_mid - np.einsum("tij,j->ti", r_pelvis, rest.hip_mid)

    def along(parent_tgt: np.ndarray, a: str, b: str, body_a: str, body_b: str) -> np.ndarray:
        return parent_tgt + _unit(p[b] - p[a]) * rest.length(body_a, body_b)

    down = np.einsum("tij,j->ti", r_pelvis, (0.0, 0.0, -1.0))

    def along_leg(parent_tgt: np.ndarray, a: str, b: str, body_a: str, body_b: str) -> np.ndarray:
        """Like `along`, but a source leg pointing straight down maps onto our rest leg, whose shank is not
        exactly vertical (so a straight source knee is a straight knee here, not a hyperextended one)."""
        turn = _rotation_between(down, _unit(p[b] - p[a]))
        return parent_tgt + np.einsum("tij,tjk,k->ti", turn, r_pelvis, rest.offset(body_a, body_b))

    for s, S in (("l", "L"), ("r", "R")):
        hip = tgt["Pelvis"] + np.einsum("tij,j->ti", r_pelvis, rest.offset("Pelvis", f"{S}_Hip"))
        tgt[f"{S}_Knee"] = along_leg(hip, f"{s}_hip", f"{s}_knee", f"{S}_Hip", f"{S}_Knee")
        tgt[f"{S}_Ankle"] = along_leg(tgt[f"{S}_Knee"], f"{s}_knee", f"{s}_ankle", f"{S}_Knee", f"{S}_Ankle")
        if f"{S}_Ankle" in rots:
            tgt[f"{S}_Toe"] = tgt[f"{S}_Ankle"] + np.einsum("tij,j->ti", rots[f"{S}_Ankle"],
                                                            rest.offset(f"{S}_Ankle", f"{S}_Toe"))
        else:
            tgt[f"{S}_Toe"] = along(tgt[f"{S}_Ankle"], f"{s}_ankle", f"{s}_toe", f"{S}_Ankle", f"{S}_Toe")
    neck_len = float(np.linalg.norm(rest.xpos["Neck"] - (rest.xpos["Pelvis"] + rest.hip_mid)))
    tgt["Neck"] = hip_mid + _unit(p["neck"] - hip_mid) * neck_len
    if "Head" in rots:
        tgt["Head"] = tgt["Neck"] + np.einsum("tij,j->ti", rots["Head"], rest.offset("Neck", "Head"))
    else:
        tgt["Head"] = along(tgt["Neck"], "neck", "head", "Neck", "Head")
    for s, S in (("l", "L"), ("r", "R")):
        tgt[f"{S}_Shoulder"] = tgt["Neck"] + np.einsum("tij,j->ti", rots["Chest"], rest.offset("Neck", f"{S}_Shoulder"))
        tgt[f"{S}_Elbow"] = along(tgt[f"{S}_Shoulder"], f"{s}_shoulder", f"{s}_elbow", f"{S}_Shoulder", f"{S}_Elbow")
        tgt[f"{S}_Wrist"] = along(tgt[f"{S}_Elbow"], f"{s}_elbow", f"{s}_wrist", f"{S}_Elbow", f"{S}_Wrist")
    return tgt, rots, scale


#: Percentile of each frame's lowest sole point taken as the floor of a source that does not give one.
FLOOR_PERCENTILE = 5.0
def source_floor(src_pos: dict[str, np.ndarray]) -> float:
    """The floor under a source's feet: a low percentile of each frame's lowest sole point rather than the lowest
    point of the clip, which a few frames of a foot through the floor (a capture glitch) would set several
    centimetres too deep, so that no frame counted as a contact."""
    lowest = np.minimum(src_pos["l_sole"][..., 2].min(axis=1), src_pos["r_sole"][..., 2].min(axis=1))
    return float(np.percentile(lowest, FLOOR_PERCENTILE))


def limb_speeds(positions: dict[str, np.ndarray], times: np.ndarray) -> np.ndarray:
    """(T-1,) fastest keypoint relative to the pelvis between consecutive frames, in leg lengths per second: a
    scale-free test for frames no body made (a rest pose before the take, a marker swap)."""
    pelvis = (positions["l_hip"] + positions["r_hip"]) / 2
    leg = np.median(np.linalg.norm(positions["l_hip"] - positions["l_knee"], axis=1) +
                    np.linalg.norm(positions["l_knee"] - positions["l_ankle"], axis=1))
    relative = np.stack([v - pelvis for v in positions.values()], axis=1)  # (T, keypoints, 3)
    step = np.linalg.norm(np.diff(relative, axis=0), axis=2).max(axis=1)
    return step / (leg * np.diff(times))


#: Within this (rad) of a bound, a joint counts as held at its limit.
LIMIT_TOL = 1e-3


def limit_hits(qpos: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> dict[str, int]:
    """joint -> frames it sits at a bound of its range, most first. The IK never leaves the ranges (so nothing is
    clipped after it); a joint held at a bound is where the source asked for more than this body's joint has."""
    at = ((qpos[:, 7:] <= lo + LIMIT_TOL) | (qpos[:, 7:] >= hi - LIMIT_TOL)).sum(axis=0)
    return {JOINT_NAMES[j]: int(at[j]) for j in np.argsort(-at, kind="stable") if at[j]}


def source_contacts(src_pos: dict[str, np.ndarray], fps: float, scale: float, floor: float | None) -> np.ndarray:
    """(T,2) foot contacts judged on the source: a sole point near the floor and slow."""
    if floor is None:
        floor = source_floor(src_pos)
    out = []
    for s in "lr":
        pts = src_pos[f"{s}_sole"] * scale  # (T,k,3)
        low = pts[..., 2] - floor * scale
        speed = np.linalg.norm(np.gradient(pts, 1.0 / fps, axis=0), axis=-1)
        out.append(np.any((low < CONTACT_HEIGHT) & (speed < CONTACT_SPEED), axis=1))
    return np.stack(out, axis=1)


def _foot_and_body_lows(model: mujoco.MjModel, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T,2) lowest point of each foot and (T, nbody) lowest point of each body's geoms."""
    bottoms = geom_bottoms(model, qpos)
    feet = bottoms[:, foot_geom_ids(model)]
    body_low = np.full((qpos.shape[0], model.nbody), np.inf)
    for g in range(model.ngeom):
        b = model.geom_bodyid[g]
        if b > 0:
            body_low[:, b] = np.minimum(body_low[:, b], bottoms[:, g])
    return np.stack([feet[:, :2].min(axis=1), feet[:, 2:].min(axis=1)], axis=1), body_low


def ground_shift(model: mujoco.MjModel, qpos: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """(T,) root height change that puts feet in contact on the floor; interpolated between contacts, and never
    letting anything go below the floor."""
    foot_low, body_low = _foot_and_body_lows(model, qpos)
    lowest = body_low.min(axis=1)
    t = np.arange(qpos.shape[0])
    in_contact = contacts.any(axis=1)
    if in_contact.any():
        need = -np.where(contacts, foot_low, np.inf).min(axis=1)
        shift = np.interp(t, t[in_contact], need[in_contact])
    else:
        shift = np.full(len(t), -lowest.min())
    return np.maximum(shift, -lowest)


def foot_slide(model: mujoco.MjModel, qpos: np.ndarray, contacts: np.ndarray, fps: float) -> float:
    """Mean horizontal speed (m/s) of each foot over the frames it is in contact: 0 for feet that stay planted,
    and a clip whose feet skate on the floor scores high (a retargeting or source problem worth looking at)."""
    if not contacts.any():
        return 0.0
    data = mujoco.MjData(model)
    ids = foot_geom_ids(model)  # left ankle and toe, right ankle and toe
    xy = np.empty((len(qpos), len(ids), 2))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        xy[t] = data.geom_xpos[ids, :2]
    feet = np.stack([xy[:, :2].mean(axis=1), xy[:, 2:].mean(axis=1)], axis=1)  # (T, 2 feet, xy)
    speed = np.linalg.norm(np.gradient(feet, 1.0 / fps, axis=0), axis=-1)
    return float(speed[contacts].mean())


def floor_metrics(model: mujoco.MjModel, qpos: np.ndarray, contacts: np.ndarray) -> tuple[float, float]:
    """(deepest foot point below the floor, largest |foot height| over contact frames), in metres."""
    foot_low, _ = _foot_and_body_lows(model, qpos)
    penetration = float(max(0.0, -foot_low.min()))
    gap = float(np.abs(foot_low[contacts]).max()) if contacts.any() else 0.0
    return penetration, gap


class Retargeter:
    """Reusable IK problem on our model; `run` converts one SourceMotion to a 30 Hz qpos trajectory."""

    def __init__(self, iterations: int = 2, first_iterations: int = 40, fps: float = 30.0):
        self.model = load_model()
        self.rest = _Rest(self.model)
        self.iterations = iterations
        self.first_iterations = first_iterations
        self.fps = fps
        self.config = mink.Configuration(self.model)
        self.tasks = {
            body: mink.FrameTask(body, "body", position_cost=pc, orientation_cost=oc, lm_damping=0.1)
            for body, pc, oc in _TASKS
        }
        self.posture = mink.PostureTask(self.model, cost=0.05)
        self.posture.set_target(self.model.qpos0)
        self.limits = [mink.ConfigurationLimit(self.model)]
        self._pos_bodies = [b for b, pc, _ in _TASKS if pc > 0]
        self._ids = np.array([self.model.body(b).id for b in self._pos_bodies])
        self._foot_bodies = [self.model.body(f"{s}_{p}").id for s in "LR" for p in ("Ankle", "Toe")]
        parents = self.model.body_parentid
        self._subtree = np.eye(self.model.nbody, dtype=bool)  # [a, b]: b is in a's subtree
        for b in range(1, self.model.nbody):
            a = parents[b]
            while a > 0:
                self._subtree[a, b] = True
                a = parents[a]
        hold_cost = np.full(self.model.nv, PLANT_HOLD)
        legs = [6 + j for j, name in enumerate(JOINT_NAMES) if name[2:5] in ("Hip", "Kne", "Ank", "Toe")]
        hold_cost[legs] = PLANT_HOLD_LEGS  # legs are what should move to reach the floor
        self.hold = mink.PostureTask(self.model, cost=hold_cost)
        self._plant_tasks = {
            "Pelvis": mink.FrameTask("Pelvis", "body", position_cost=(10.0, 10.0, 0.1), orientation_cost=1.0),
            **{f"{s}_{p}": mink.FrameTask(f"{s}_{p}", "body", position_cost=10.0, orientation_cost=1.0)
               for s in "LR" for p in ("Ankle", "Toe")},
        }
        self._lift_tasks = {
            b: mink.FrameTask(self.model.body(b).name, "body", position_cost=(0.0, 0.0, 20.0), orientation_cost=0.0)
            for b in range(1, self.model.nbody)
        }

    def _orient(self, rots: dict) -> None:
        """Constrain orientations only where the source gives them. A body with no source orientation (the head and
        feet of BVH and ASF/AMC takes) is left to its position target and the posture task's pull to rest: an
        identity target there would ask it to face the world's +x and hold its twist joints at their stops."""
        for body, _, cost in _TASKS:
            self.tasks[body].set_orientation_cost(cost if body in rots else 0.0)

    def _solve(self, targets: dict, rots: dict, t: int, iterations: int) -> None:
        """A few IK steps from the current configuration towards frame t's targets."""
        eye = np.eye(3)
        for body, task in self.tasks.items():
            rot = rots[body][t] if body in rots else eye  # identity: the cost is 0 (`_orient`)
            pos = targets[body][t] if body in targets else np.zeros(3)  # zeros: orientation-only task
            task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(rot), pos))
        self._iterate([*self.tasks.values(), self.posture], iterations)

    def _iterate(self, tasks: list[mink.Task], iterations: int) -> None:
        for _ in range(iterations):
            vel = mink.solve_ik(self.config, tasks, 1.0, solver="daqp", damping=1e-3, limits=self.limits)
            self.config.integrate_inplace(vel, 1.0)

    def _plant(self, qpos: np.ndarray, contacts: np.ndarray) -> np.ndarray:
        """Ground the clip, then re-solve frames where a contact foot floats or another body part goes through
        the floor: contact feet get targets on the floor, penetrating bodies targets just above it, and a posture
        task holds everything else where it was (the hips may move up or down)."""
        qpos = qpos.copy()
        qpos[:, 2] += ground_shift(self.model, qpos, contacts)
        foot_low, body_low = _foot_and_body_lows(self.model, qpos)
        foot_low = np.where(contacts, foot_low, 0.0)
        body_low[:, self._foot_bodies] = np.inf
        bad = np.flatnonzero((np.abs(foot_low) > PLANT_TOL).any(axis=1) | (body_low.min(axis=1) < -PLANT_TOL))
        for t in bad:
            self.config.update(qpos[t])
            self.hold.set_target(qpos[t])
            tasks: list[mink.Task] = [self.hold]
            for body, task in self._plant_tasks.items():
                pose = self.config.get_transform_frame_to_world(body, "body")
                k = "LR".index(body[0]) if body[0] in "LR" else None
                drop = foot_low[t, k] if k is not None else 0.0
                task.set_target(mink.SE3.from_rotation_and_translation(pose.rotation(),
                                                                       pose.translation() - (0, 0, drop)))
                tasks.append(task)
            for b in np.flatnonzero(body_low[t] < 0):
                task = self._lift_tasks[int(b)]
                lift = self.config.data.xpos[b] - (0, 0, body_low[t, b] - PLANT_MARGIN)
                task.set_target(mink.SE3.from_translation(lift))
                tasks.append(task)
            self._iterate(tasks, PLANT_ITERATIONS)
            qpos[t] = self.config.q
        return qpos

    def run(self, src: SourceMotion) -> tuple[np.ndarray, RetargetReport]:
        """Retarget one source clip: (qpos (T,76) at self.fps, report)."""
        with single_threaded_blas():
            return self._run(src)

    def _run(self, src: SourceMotion) -> tuple[np.ndarray, RetargetReport]:
        start = time.perf_counter()
        pos, rot, _ = _resample(src, self.fps)
        targets, rots, scale = build_targets(pos, rot, self.rest)
        self._orient(rots)
        n = targets["Pelvis"].shape[0]
        q = self.model.qpos0.copy()
        q[:3] = targets["Pelvis"][0]
        q[3:7] = Rotation.from_matrix(rots["Pelvis"][0]).as_quat(scalar_first=True)
        self.config.update(q)
        qpos = np.empty((n, self.model.nq))
        err = 0.0
        for t in range(n):
            q = self.config.q.copy()
            q[:3] = targets["Pelvis"][t]  # warm start: previous joints, root moved to its new target
            self.config.update(q)
            self._solve(targets, rots, t, self.first_iterations if t == 0 else self.iterations)
            qpos[t] = self.config.q
            wanted = np.stack([targets[b][t] for b in self._pos_bodies])
            err += np.linalg.norm(self.config.data.xpos[self._ids] - wanted, axis=1).mean()
        contacts = source_contacts(pos, self.fps, scale, src.floor)
        for _ in range(PLANT_ROUNDS):
            qpos = self._plant(qpos, contacts)
        lo, hi = joint_ranges(self.model).T
        over = (qpos[:, 7:] < lo - 1e-4) | (qpos[:, 7:] > hi + 1e-4)
        clipped = {JOINT_NAMES[j]: int(c) for j, c in enumerate(over.sum(axis=0)) if c}
        qpos[:, 7:] = np.clip(qpos[:, 7:], lo, hi)
        at_limits = limit_hits(qpos, lo, hi)
        qpos[:, 2] += ground_shift(self.model, qpos, contacts)
        penetration, gap = floor_metrics(self.model, qpos, contacts)
        report = RetargetReport(
            name=src.name, frames=n, seconds=n / self.fps, compute_seconds=time.perf_counter() - start,
            clipped=clipped, max_penetration=penetration, max_contact_gap=gap, keypoint_error=err / n,
            foot_slide=foot_slide(self.model, qpos, contacts, self.fps), contacts=contacts,
            contact_share=float(contacts.any(axis=1).mean()), at_limits=at_limits,
            peak_limb_speed=float(limb_speeds(src.positions, src.times).max()),
        )
        return qpos, report
