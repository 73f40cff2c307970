"""AMASS/SMPL import: a synthetic SMPL file built from known rotations comes back as the expected joint angles.

Convention under test (see motions/importers/amass.py): SMPL body axes are x left, y up, z forward; ours are
x forward, y left, z up; AMASS worlds are z up, so a person standing upright facing world +x has the SMPL root
orientation that maps SMPL's (x, y, z) onto world (y, z, x).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from humanoid_env.model import BODY_NAMES, JOINT_NAMES, joint_ranges
from motions.importers import detect_format, import_file
from motions.importers.amass import SMPL_INDEX, SMPL_TO_OURS, AmassFormatError, read_amass

BASIS = Rotation.from_matrix(SMPL_TO_OURS)


def _smpl_npz(path, angles: np.ndarray, root_ours: Rotation, trans: np.ndarray, fps: float, up_y: bool = False,
              width: int = 72):
    """Write an AMASS file (SMPL: width 72, SMPL+H: 156) whose joints have our hinge angles `angles` (T,69)."""
    n = angles.shape[0]
    poses = np.zeros((n, width))
    root_world = root_ours * BASIS  # body SMPL axes -> our axes -> world
    if up_y:
        to_y_up = Rotation.from_matrix(np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]))
        root_world = to_y_up * root_world
        trans = trans @ to_y_up.as_matrix().T
    poses[:, :3] = root_world.as_rotvec()
    for i, body in enumerate(BODY_NAMES[1:]):
        ours = Rotation.from_euler("XYZ", angles[:, 3 * i:3 * i + 3])
        j = SMPL_INDEX[body]
        if j >= 22 and width != 72:
            j += 18  # SMPL+H: slots 22, 23 are fingers; put the hand rotations on other fingers (40, 41): ignored
        poses[:, 3 * j:3 * j + 3] = (BASIS.inv() * ours * BASIS).as_rotvec()
    np.savez(path, poses=poses, trans=trans, mocap_framerate=np.float64(fps), betas=np.zeros(16),
             gender=np.str_("neutral"))
    return path


def _known_motion(n: int = 40):
    rng = np.random.default_rng(0)
    lo, hi = joint_ranges().T
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    t = np.linspace(0, 1, n)[:, None]
    a0, a1 = mid + 0.5 * half * rng.uniform(-1, 1, (2, 69))
    angles = (1 - t) * a0 + t * a1  # smooth, inside the ranges, away from Euler singularities
    yaw = np.linspace(0.0, 0.8, n)
    root = Rotation.from_euler("z", yaw[:, None])
    trans = np.stack([np.linspace(0, 1.2, n), np.zeros(n), np.full(n, 0.95)], axis=1)
    return angles, root, trans, yaw


def test_known_rotations_come_back_as_joint_angles(tmp_path):
    angles, root, trans, yaw = _known_motion()
    path = _smpl_npz(tmp_path / "synthetic_smpl.npz", angles, root, trans, fps=60.0)
    assert detect_format(path) == "amass"
    clip, report = import_file(path, use_cache=False)
    assert clip.n_frames == 20 and report.clipped == {}  # 60 Hz -> 30 Hz, every second frame
    np.testing.assert_allclose(clip.qpos[:, 7:], angles[::2], atol=1e-6)
    got_yaw = Rotation.from_quat(clip.qpos[:, 3:7], scalar_first=True).as_euler("ZYX")[:, 0]
    np.testing.assert_allclose(got_yaw, yaw[::2], atol=1e-6)
    np.testing.assert_allclose(clip.qpos[:, :2], trans[::2, :2], atol=1e-9)
    assert report.max_penetration <= 0.02


def test_knee_bend_convention():
    """A knee flexion in SMPL (positive rotation about SMPL's x = left axis) is our positive Knee_y, also past 90 deg."""
    from motions.importers.amass import smpl_to_qpos

    poses = np.zeros((2, 72))
    poses[:, 3 * 4] = [0.8, 2.0]  # SMPL joint 4 = left knee
    poses[:, :3] = (Rotation.identity() * BASIS).as_rotvec()  # upright, facing +x
    q = smpl_to_qpos(poses, np.zeros((2, 3)))
    k = 7 + JOINT_NAMES.index("L_Knee_x")
    np.testing.assert_allclose(q[:, k:k + 3], [[0, 0.8, 0], [0, 2.0, 0]], atol=1e-9)
    np.testing.assert_allclose(q[0, 3:7], [1, 0, 0, 0], atol=1e-12)


def test_y_up_smplh_source_with_option(tmp_path):
    angles, root, trans, _ = _known_motion(20)
    path = _smpl_npz(tmp_path / "y_up.npz", angles, root, trans, fps=30.0, up_y=True, width=156)
    clip, _ = import_file(path, up_axis="y", use_cache=False)
    hands = [JOINT_NAMES.index(f"{s}_Hand_{a}") for s in "LR" for a in "xyz"]
    body = np.setdiff1d(np.arange(69), hands)
    np.testing.assert_allclose(clip.qpos[:, 7 + body], angles[:, body], atol=1e-6)
    np.testing.assert_allclose(clip.qpos[:, 7 + np.array(hands)], 0.0, atol=1e-12)  # SMPL+H: hands stay at rest
    np.testing.assert_allclose(clip.qpos[:, :2], trans[:, :2], atol=1e-9)


def test_out_of_range_angles_are_clipped_and_counted(tmp_path):
    angles, root, trans, _ = _known_motion(10)
    k = JOINT_NAMES.index("L_Knee_y")
    angles[:, k] = -0.5  # hyperextended knee, below the -5 deg limit
    clip, report = import_file(_smpl_npz(tmp_path / "hyper.npz", angles, root, trans, 30.0), use_cache=False)
    assert report.clipped.get("L_Knee_y") == 10
    assert np.all(clip.qpos[:, 7 + k] == pytest.approx(joint_ranges()[k, 0]))


@pytest.mark.parametrize(
    "arrays, message",
    [
        (dict(trans=np.zeros((5, 3)), mocap_framerate=30.0), "missing 'poses'"),
        (dict(poses=np.zeros((5, 72)), trans=np.zeros((5, 3))), "missing 'mocap_framerate'"),
        (dict(poses=np.zeros((5, 60)), trans=np.zeros((5, 3)), mocap_framerate=30.0), "poses must be a float array (T, >=72)"),
        (dict(poses=np.zeros((5, 72)), trans=np.zeros((4, 3)), mocap_framerate=30.0), "trans must be float (T, 3)"),
        (dict(poses=np.full((5, 72), np.nan), trans=np.zeros((5, 3)), mocap_framerate=30.0), "NaN or inf"),
        (dict(poses=np.zeros((5, 72)), trans=np.zeros((5, 3)), mocap_framerate=-1.0), "outside"),
    ],
)
def test_malformed_amass_files(tmp_path, arrays, message):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(AmassFormatError) as err:
        read_amass(path)
    assert str(path) in str(err.value) and message in str(err.value)
