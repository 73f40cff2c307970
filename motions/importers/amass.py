"""AMASS / SMPL `.npz` (poses, trans, mocap_framerate, optional betas) -> our joint angles.

Our humanoid has SMPL's topology and T-pose rest, so no IK is needed: each SMPL joint's local rotation is moved
from SMPL's body axes (x left, y up, z forward) into ours (x forward, y left, z up) by a change of basis, and
decomposed into our three nested hinges (R = Rx(a) Ry(b) Rz(c), scipy's intrinsic "XYZ").

Assumption about the world frame: AMASS stores motions z up (its root orientation already turns SMPL's y-up body
into a z-up world), so `up_axis="z"` is the default. Raw SMPL fits in a y-up world use `up_axis="y"`.
Body shape (`betas`) is ignored: all motions are played by our one neutral body; the root translation is used as
is (metres) and the clip is then put on the floor with the same foot-contact grounding as the IK importers.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from humanoid_env.model import BODY_NAMES, JOINT_NAMES, joint_ranges, load_model
from motions.kinematics import resample_qpos
from motions.limits import MIN_FRAME_SECONDS, check_frame_times, max_clip_seconds
from motions.npz import read_npz
from motions.retarget import RetargetReport, floor_metrics, foot_slide, ground_shift

#: SMPL joint index for each of our non-root bodies, in BODY_NAMES[1:] order.
SMPL_INDEX = {
    "L_Hip": 1, "L_Knee": 4, "L_Ankle": 7, "L_Toe": 10, "R_Hip": 2, "R_Knee": 5, "R_Ankle": 8, "R_Toe": 11,
    "Torso": 3, "Spine": 6, "Chest": 9, "Neck": 12, "Head": 15, "L_Thorax": 13, "L_Shoulder": 16, "L_Elbow": 18,
    "L_Wrist": 20, "L_Hand": 22, "R_Thorax": 14, "R_Shoulder": 17, "R_Elbow": 19, "R_Wrist": 21, "R_Hand": 23,
}
#: Columns are SMPL's body axes expressed in ours: SMPL x (left) -> our y, y (up) -> our z, z (forward) -> our x.
SMPL_TO_OURS = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])
#: y-up world to z-up world (+90 deg about x).
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
CONTACT_HEIGHT = 0.03
CONTACT_SPEED = 0.5


class AmassFormatError(ValueError):
    """An AMASS/SMPL file that cannot be read; the message names the file and the problem."""


def read_amass(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """(poses (T,72+), trans (T,3), fps), validated; never unpickles."""
    path = Path(path)
    data = read_npz(path, ("poses", "trans", "mocap_framerate", "mocap_frame_rate"), AmassFormatError, "AMASS .npz",
                    max_rows=int(max_clip_seconds() / MIN_FRAME_SECONDS) + 1)
    for key in ("poses", "trans"):
        if key not in data:
            raise AmassFormatError(f"{path}: missing {key!r} (AMASS files have poses, trans, mocap_framerate)")
    fps = data.get("mocap_framerate", data.get("mocap_frame_rate"))
    if fps is None:
        raise AmassFormatError(f"{path}: missing 'mocap_framerate'")
    poses, trans = data["poses"], data["trans"]
    if poses.ndim != 2 or poses.shape[1] < 72 or poses.dtype.kind != "f":
        raise AmassFormatError(f"{path}: poses must be a float array (T, >=72), got {poses.dtype} {poses.shape}")
    if trans.shape != (poses.shape[0], 3) or trans.dtype.kind != "f":
        raise AmassFormatError(f"{path}: trans must be float (T, 3) matching poses, got {trans.dtype} {trans.shape}")
    if poses.shape[0] < 2:
        raise AmassFormatError(f"{path}: needs at least 2 frames, got {poses.shape[0]}")
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(trans))):
        raise AmassFormatError(f"{path}: poses or trans contain NaN or inf")
    if fps.size != 1 or fps.dtype.kind not in "fiu":
        raise AmassFormatError(f"{path}: mocap_framerate must be a number, got {fps!r}")
    rate = float(fps.reshape(()))
    if np.isnan(rate) or rate == 0:  # no frame time at all; other rates out of range are named below
        raise AmassFormatError(f"{path}: mocap_framerate must be a positive, finite number of frames per second, "
                               f"got {rate:g}")
    check_frame_times(1.0 / rate, f"{path}: mocap_framerate {rate:g}", AmassFormatError, repeats=poses.shape[0] - 1)
    return poses.astype(np.float64), trans.astype(np.float64), rate


def smpl_to_qpos(poses: np.ndarray, trans: np.ndarray, up_axis: str = "z") -> np.ndarray:
    """(T,76) qpos (not grounded) from SMPL axis-angle poses and root translations.

    Only plain SMPL (72 values per frame) has hand joints at 22 and 23; in SMPL+H (156) and SMPL-X (165) those
    slots hold a finger or the jaw, so our hand bodies stay at rest for them.
    """
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    world = Y_UP_TO_Z_UP if up_axis == "y" else np.eye(3)
    n = poses.shape[0]
    basis = Rotation.from_matrix(SMPL_TO_OURS)
    qpos = np.zeros((n, 76))
    root = Rotation.from_matrix(world) * Rotation.from_rotvec(poses[:, :3]) * basis.inv()
    qpos[:, :3] = trans @ world.T
    qpos[:, 3:7] = root.as_quat(scalar_first=True)
    ranges = joint_ranges()
    for i, body in enumerate(BODY_NAMES[1:]):
        j = SMPL_INDEX[body]
        if j >= 22 and poses.shape[1] != 72:
            continue
        local = basis * Rotation.from_rotvec(poses[:, 3 * j:3 * j + 3]) * basis.inv()
        qpos[:, 7 + 3 * i:10 + 3 * i] = hinge_angles(local, ranges[3 * i:3 * i + 3])
    return qpos


def hinge_angles(rot: Rotation, ranges: np.ndarray) -> np.ndarray:
    """(T,3) x-y-z hinge angles of rotations, choosing per frame the one of the two equivalent Euler solutions
    that lies closer to the joint ranges (scipy returns the middle angle in [-90, 90] deg, but a knee or hip
    can bend further than 90 deg)."""
    a = rot.as_euler("XYZ")
    b = np.stack([a[:, 0] + np.pi, np.pi - a[:, 1], a[:, 2] + np.pi], axis=1)
    b = (b + np.pi) % (2 * np.pi) - np.pi

    def excess(x: np.ndarray) -> np.ndarray:
        return (np.clip(ranges[:, 0] - x, 0, None) + np.clip(x - ranges[:, 1], 0, None)).sum(axis=1)

    pick_b = excess(b) < excess(a) - 1e-9
    return np.where(pick_b[:, None], b, a)


def foot_contacts(model, qpos: np.ndarray, fps: float) -> np.ndarray:
    """(T,2) contacts judged on our own body: a foot near the clip's lowest foot height, not moving vertically."""
    from motions.kinematics import foot_geom_ids, geom_bottoms

    feet = geom_bottoms(model, qpos)[:, foot_geom_ids(model)]
    low = np.stack([feet[:, :2].min(axis=1), feet[:, 2:].min(axis=1)], axis=1)
    vz = np.abs(np.gradient(low, 1.0 / fps, axis=0))
    return (low - low.min() < CONTACT_HEIGHT) & (vz < CONTACT_SPEED)


def import_amass(path: str | Path, fps: float = 30.0, up_axis: str = "z",
                 source_fps: float | None = None) -> tuple[np.ndarray, RetargetReport, dict]:
    """(qpos at `fps`, report, provenance) for one AMASS/SMPL file; `source_fps` overrides its mocap_framerate."""
    import time

    path = Path(path)
    start = time.perf_counter()
    poses, trans, src_fps = read_amass(path)
    src_fps = source_fps or src_fps
    qpos = resample_qpos(smpl_to_qpos(poses, trans, up_axis), src_fps, fps)
    model = load_model()
    lo, hi = joint_ranges(model).T
    over = (qpos[:, 7:] < lo - 1e-4) | (qpos[:, 7:] > hi + 1e-4)
    clipped = {JOINT_NAMES[j]: int(c) for j, c in enumerate(over.sum(axis=0)) if c}
    qpos[:, 7:] = np.clip(qpos[:, 7:], lo, hi)
    contacts = foot_contacts(model, qpos, fps)
    qpos[:, 2] += ground_shift(model, qpos, contacts)
    penetration, gap = floor_metrics(model, qpos, contacts)
    report = RetargetReport(
        name=path.stem, frames=qpos.shape[0], seconds=qpos.shape[0] / fps, compute_seconds=time.perf_counter() - start,
        clipped=clipped, max_penetration=penetration, max_contact_gap=gap, contacts=contacts,
        foot_slide=foot_slide(model, qpos, contacts, fps), contact_share=float(contacts.any(axis=1).mean()),
    )
    return qpos, report, {"source": f"AMASS/SMPL {path.name}", "license": "see the AMASS license of the source dataset"}
