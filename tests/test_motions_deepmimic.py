"""All DeepMimic clips in ../shared import through the mink IK retargeter into plausible clips for our body."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from humanoid_env.model import JOINT_NAMES, joint_ranges, load_model
from humanoid_env.observation import observe
from motions.importers import detect_format, import_file
from motions.importers.deepmimic import DeepMimicFormatError, load_deepmimic
from motions.kinematics import foot_geom_ids, geom_bottoms

SHARED = Path(__file__).parents[1].parent / "shared" / "mocap" / "deepmimic" / "motions"
CLIPS = sorted(SHARED.glob("humanoid3d_*.txt"))
needs_data = pytest.mark.skipif(not CLIPS, reason=f"DeepMimic clips not found in {SHARED}")
KNEES = [JOINT_NAMES.index(f"{s}_Knee_y") for s in "LR"]


@pytest.fixture(scope="module")
def imported():
    """Every clip converted once for this module (about 30 s on 2 shared cores), without the cache."""
    return {p.stem: import_file(p, use_cache=False) for p in CLIPS}


@needs_data
def test_all_twenty_clips_import(imported):
    assert len(CLIPS) == 20
    assert all(detect_format(p) == "deepmimic" for p in CLIPS)
    total = sum(clip.seconds for clip, _ in imported.values())
    assert 200 < total < 240  # about 225 s of motion in the folder


@needs_data
def test_clips_are_finite_and_replay_to_their_obs(imported):
    model = load_model()
    for name, (clip, _) in imported.items():
        for arr in (clip.qpos, clip.qvel, clip.obs):
            assert np.all(np.isfinite(arr)), name
        rows = slice(0, None, max(1, clip.n_frames // 20))
        np.testing.assert_allclose(observe(model, clip.qpos[rows], clip.qvel[rows]), clip.obs[rows], atol=1e-5)


@needs_data
def test_joint_angles_inside_ranges_with_clipping_reported(imported):
    lo, hi = joint_ranges().T
    for name, (clip, report) in imported.items():
        assert np.all(clip.qpos[:, 7:] >= lo - 1e-9) and np.all(clip.qpos[:, 7:] <= hi + 1e-9), name
        assert all(j in JOINT_NAMES and 0 < n <= report.frames for j, n in report.clipped.items()), name


@needs_data
def test_feet_on_the_floor(imported):
    """No foot point below -2 cm anywhere; at the source's foot contacts, that foot is within 2 cm of the floor."""
    model = load_model()
    for name, (clip, report) in imported.items():
        feet = geom_bottoms(model, clip.qpos)[:, foot_geom_ids(model)]
        low = np.stack([feet[:, :2].min(axis=1), feet[:, 2:].min(axis=1)], axis=1)
        assert low.min() >= -0.02, f"{name}: foot {-low.min():.3f} m below the floor"
        contacts = report.contacts
        assert contacts.shape == low.shape, name
        if contacts.any():
            assert np.abs(low[contacts]).max() <= 0.02, f"{name}: foot {np.abs(low[contacts]).max():.3f} m off the floor at a contact"
        assert report.max_penetration <= 0.02 and report.max_contact_gap <= 0.02


@needs_data
def test_standing_frames_have_human_pelvis_height(imported):
    n_standing = 0
    for name, (clip, report) in imported.items():
        up_z = 1 - 2 * (clip.qpos[:, 4] ** 2 + clip.qpos[:, 5] ** 2)  # pelvis z axis, z component
        knees = clip.qpos[:, 7 + np.array(KNEES)]
        # upright, and every foot on the floor has a nearly straight knee (double or single support)
        standing = report.contacts.any(axis=1) & (up_z > 0.9) & np.all((knees < 0.35) | ~report.contacts, axis=1)
        n_standing += standing.sum()
        z = clip.qpos[standing, 2]
        assert np.all((z >= 0.8) & (z <= 1.1)), f"{name}: standing pelvis heights {z.min():.2f}..{z.max():.2f}"
    assert n_standing > 1000  # the walks are mostly standing frames


@needs_data
def test_walk_retarget_tracks_the_source(imported):
    """The walk keeps the source's speed (scaled to our legs) and its step rhythm."""
    clip, report = imported["humanoid3d_walk"]
    src = load_deepmimic(SHARED / "humanoid3d_walk.txt")
    src_speed = np.linalg.norm(src.positions["l_hip"][-1, :2] - src.positions["l_hip"][0, :2]) / src.times[-1]
    speed = np.linalg.norm(clip.qpos[-1, :2] - clip.qpos[0, :2]) / ((clip.n_frames - 1) / 30)
    assert speed == pytest.approx(src_speed, rel=0.1)
    assert report.keypoint_error < 0.02  # metres, mean over the tracked bodies
    contacts = report.contacts
    assert contacts[:, 0].any() and contacts[:, 1].any() and not contacts.all()


def test_malformed_deepmimic_files(tmp_path):
    good_row = [0.033] + [0.0, 0.9, 0.0] + [1.0, 0, 0, 0] * 2 + [1.0, 0, 0, 0, 1.0, 0, 0, 0] + [0.0] + [1.0, 0, 0, 0] * 2 + [0.0] + [1.0, 0, 0, 0] + [0.0] + [1.0, 0, 0, 0] * 2 + [0.0]
    assert len(good_row) == 44
    cases = {
        "truncated.txt": ('{"Loop": "wrap", "Frames": [[0.1, 2', "not a readable DeepMimic JSON"),
        "short_row.txt": (json.dumps({"Loop": "none", "Frames": [good_row, good_row[:40]]}), "frame 1 does not have 44 numbers"),
        "nan.txt": (json.dumps({"Loop": "none", "Frames": [good_row, good_row]}).replace("0.9", "NaN", 1), "NaN or inf"),
        "zero_quat.txt": (json.dumps({"Loop": "none", "Frames": [good_row, good_row, good_row[:4] + [0, 0, 0, 0] + good_row[8:]]}), "root quaternion has zero length"),
        "bad_loop.txt": (json.dumps({"Loop": "sometimes", "Frames": [good_row] * 3}), '"Loop" must be'),
        "no_frames.txt": (json.dumps({"Loop": "none"}), 'no "Frames"'),
    }
    for fname, (text, message) in cases.items():
        path = tmp_path / fname
        path.write_text(text)
        with pytest.raises(DeepMimicFormatError) as err:
            load_deepmimic(path)
        assert str(path) in str(err.value) and message in str(err.value), (fname, str(err.value))
    ok = tmp_path / "ok.txt"
    ok.write_text(json.dumps({"Loop": "none", "Frames": [good_row] * 10}))
    assert load_deepmimic(ok).positions["l_ankle"].shape == (10, 3)


@needs_data
def test_looping_walk_repeats_without_jumps():
    clip, report = import_file(SHARED / "humanoid3d_walk.txt", loop_seconds=5.0, use_cache=False)
    assert clip.seconds >= 5.0 and clip.n_frames > 3 * report.frames
    step = np.linalg.norm(np.diff(clip.qpos[:, :2], axis=0), axis=1)
    assert step.max() < 2.5 * np.median(step)  # no jump back at the cycle seams
    joints_step = np.abs(np.diff(clip.qpos[:, 7:], axis=0)).max()
    assert joints_step < 0.5
    assert np.linalg.norm(clip.qpos[-1, :2] - clip.qpos[0, :2]) > 4.0  # kept walking: about 1.4 m/s
