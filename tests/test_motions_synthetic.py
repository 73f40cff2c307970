"""Built-in synthetic clips: deterministic, grounded, and the static ones holdable by the PD controller."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from humanoid_env.model import N_SUBSTEPS, joint_ranges, load_model
from humanoid_env.observation import observe
from motions import synthetic
from motions.kinematics import foot_geom_ids, geom_bottoms


@pytest.fixture(scope="module")
def clips():
    return {c.name: c for c in synthetic.default_clips()}


def test_clips_are_deterministic_and_consistent(clips):
    assert sorted(clips) == ["arm_raise", "squat", "stand", "tpose", "turn", "walk"]
    again = synthetic.walk()
    np.testing.assert_array_equal(again.qpos, clips["walk"].qpos)
    model = load_model()
    lo, hi = joint_ranges(model).T
    for c in clips.values():
        assert c.fps == 30 and c.n_frames >= 60
        assert np.all(c.qpos[:, 7:] >= lo - 1e-9) and np.all(c.qpos[:, 7:] <= hi + 1e-9)
        np.testing.assert_allclose(observe(model, c.qpos[::10], c.qvel[::10]), c.obs[::10], atol=1e-6)


def test_clips_stand_on_the_floor(clips):
    model = load_model()
    for c in clips.values():
        bottoms = geom_bottoms(model, c.qpos)
        np.testing.assert_allclose(bottoms.min(axis=1), 0.0, atol=1e-6, err_msg=c.name)  # touching, not sinking
        assert bottoms[:, foot_geom_ids(model)].min(axis=1).max() < 1e-6, c.name  # a foot carries the weight


def test_walk_moves_forward_without_sliding_the_stance_foot(clips):
    walk = clips["walk"]
    assert walk.qpos[-1, 0] - walk.qpos[0, 0] > 1.0  # about 0.3 m/s or more along +x
    assert abs(walk.qpos[-1, 1] - walk.qpos[0, 1]) < 0.1
    turn = clips["turn"]
    yaw = 2 * np.arctan2(turn.qpos[:, 6], turn.qpos[:, 3])
    assert yaw[-1] - yaw[0] == pytest.approx(np.pi / 2, abs=1e-6)


@pytest.mark.parametrize("name", ["stand", "tpose", "arm_raise", "squat"])
def test_pd_controller_holds_the_clip(clips, name):
    """Track the clip with ctrl = joint targets (position actuators) in the real simulation: stays upright, close."""
    clip = clips[name]
    model = load_model()
    data = mujoco.MjData(model)
    data.qpos[:] = clip.qpos[0]
    data.qvel[:] = clip.qvel[0]
    mujoco.mj_forward(model, data)
    worst_height, worst_up = 0.0, 1.0
    for t in range(1, clip.n_frames):
        data.ctrl[:] = clip.qpos[t, 7:]
        mujoco.mj_step(model, data, N_SUBSTEPS)
        worst_height = max(worst_height, abs(data.qpos[2] - clip.qpos[t, 2]))
        worst_up = min(worst_up, data.xmat[1, 8])  # z component of the pelvis' up axis
    assert worst_up > 0.98, f"{name}: pelvis tilted (up.z = {worst_up:.3f})"
    assert worst_height < 0.03, f"{name}: pelvis height off by {worst_height:.3f} m"
    assert np.abs(data.qpos[:2] - clip.qpos[-1, :2]).max() < 0.1, f"{name}: drifted {data.qpos[:2] - clip.qpos[-1, :2]}"
    assert np.abs(data.qpos[7:] - clip.qpos[-1, 7:]).max() < 0.15, f"{name}: joints far from the clip"
