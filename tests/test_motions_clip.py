"""Clip format (round trip, validation of malformed files) and the trajectory math behind it."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from humanoid_env.model import default_qpos, load_model
from humanoid_env.observation import observe
from motions.clip import Clip, ClipFormatError, from_qpos, load_clip, save_clip
from motions.kinematics import finite_difference_qvel, repeat_loop, resample_qpos


def _clip(n: int = 12) -> Clip:
    q = np.repeat(default_qpos()[None], n, axis=0)
    t = np.arange(n) / 30.0
    q[:, 0] = 0.5 * t
    q[:, 7 + 40] = 0.3 * np.sin(3 * t)  # a shoulder joint
    yaw = 0.4 * t
    q[:, 3], q[:, 6] = np.cos(yaw / 2), np.sin(yaw / 2)
    return from_qpos(q, name="probe", source="test", license="MIT")


def test_round_trip_preserves_everything(tmp_path):
    clip = _clip()
    path = save_clip(clip, tmp_path / "probe.npz")
    back = load_clip(path)
    np.testing.assert_array_equal(back.qpos, clip.qpos)
    np.testing.assert_array_equal(back.qvel, clip.qvel)
    np.testing.assert_array_equal(back.obs, clip.obs)
    assert (back.name, back.source, back.license, back.fps) == ("probe", "test", "MIT", 30)
    assert back.obs.dtype == np.float32 and back.qpos.dtype == np.float64


def test_kinematic_replay_reproduces_obs(tmp_path):
    clip = load_clip(save_clip(_clip(), tmp_path / "c.npz"))
    np.testing.assert_allclose(observe(load_model(), clip.qpos, clip.qvel), clip.obs, atol=1e-6)


def test_root_velocity_follows_mujoco_conventions():
    """Linear velocity in the world frame, angular velocity in the root's local frame."""
    model = load_model()
    n, fps = 20, 30.0
    t = np.arange(n) / fps
    q = np.repeat(default_qpos()[None], n, axis=0)
    q[:, 0] = 0.7 * t
    tilt = Rotation.from_euler("x", 0.5)  # tilted body: local and world angular velocity differ
    spin = Rotation.from_euler("z", 1.2 * t[:, None])  # world yaw rate 1.2 rad/s
    q[:, 3:7] = (spin * tilt).as_quat(scalar_first=True)
    qvel = finite_difference_qvel(model, q, fps)
    np.testing.assert_allclose(qvel[:, :3], np.tile([0.7, 0, 0], (n, 1)), atol=1e-9)
    local_expected = tilt.inv().apply([0, 0, 1.2])
    np.testing.assert_allclose(qvel[1:-1, 3:6], np.tile(local_expected, (n - 2, 1)), atol=1e-3)
    assert abs(local_expected[1]) > 0.5  # the test would catch a world-frame result


def test_resample_uses_slerp_and_keeps_duration():
    q = np.repeat(default_qpos()[None], 61, axis=0)
    yaw = np.linspace(0, 2.0, 61)
    q[:, 3], q[:, 6] = np.cos(yaw / 2), np.sin(yaw / 2)
    q[:, 7] = np.linspace(0, 0.6, 61)
    out = resample_qpos(q, 60, 30)
    assert out.shape[0] == 31
    np.testing.assert_allclose(np.linalg.norm(out[:, 3:7], axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(2 * np.arctan2(out[:, 6], out[:, 3]), yaw[::2], atol=1e-9)
    np.testing.assert_allclose(out[:, 7], q[::2, 7], atol=1e-12)


def test_repeat_loop_accumulates_root_offset():
    n = 31
    q = np.repeat(default_qpos()[None], n, axis=0)
    q[:, 0] = np.linspace(0, 1.0, n)  # one cycle walks 1 m forward
    out = repeat_loop(q, 3)
    assert out.shape[0] == 3 * (n - 1) + 1
    np.testing.assert_allclose(out[-1, 0], 3.0, atol=1e-9)
    assert np.all(np.diff(out[:, 0]) > 0)  # no jump back to the start
    # turning cycles: a quarter turn per cycle rotates the next cycle's displacement
    q[:, 3], q[:, 6] = np.cos(np.linspace(0, np.pi / 4, n)), np.sin(np.linspace(0, np.pi / 4, n))
    out = repeat_loop(q, 2)
    np.testing.assert_allclose(out[-1, :2], [1.0, 1.0], atol=1e-9)


def _write(path, **arrays):
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def _good_arrays(clip: Clip) -> dict:
    return dict(qpos=clip.qpos, qvel=clip.qvel, obs=clip.obs, fps=np.int64(30), name=np.str_("x"),
                source=np.str_("s"), license=np.str_("l"))


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda a: a.pop("obs"), "missing keys ['obs']"),
        (lambda a: a.update(qpos=a["qpos"][:, :70]), "qpos must have shape (T, 76)"),
        (lambda a: a["qvel"].__setitem__((3, 5), np.nan), "qvel has NaN or inf values (first at frame 3)"),
        (lambda a: a.update(fps=np.int64(60)), "fps must be 30"),
        (lambda a: a.update(qpos=a["qpos"][:1], qvel=a["qvel"][:1], obs=a["obs"][:1]), "at least 2 are needed"),
        (lambda a: a.update(obs=a["obs"][:-1]), "different lengths"),
        (lambda a: a.update(qpos=a["qpos"].astype(np.int64)), "qpos must be a floating-point array"),
        (lambda a: a.update(name=np.array([1, 2])), "name must be a string"),
        (lambda a: a.update(obs=a["obs"] + np.float32(0.05)), "obs do not match the humanoid's observation function"),
    ],
)
def test_malformed_clip_files_are_rejected_with_the_file_and_the_problem(tmp_path, mutate, message):
    arrays = _good_arrays(_clip())
    mutate(arrays)
    path = _write(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ClipFormatError) as err:
        load_clip(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_non_npz_and_pickled_files_are_rejected(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 definitely not a zip")
    with pytest.raises(ClipFormatError, match="not a valid clip archive"):
        load_clip(junk)
    arrays = _good_arrays(_clip())
    arrays["name"] = np.array(["x"], dtype=object)  # object arrays need pickle
    path = _write(tmp_path / "pickled.npz", **arrays)
    with pytest.raises(ClipFormatError, match="pickled.npz"):
        load_clip(path)
    with pytest.raises(ClipFormatError, match="no such clip file"):
        load_clip(tmp_path / "missing.npz")


def test_failed_save_leaves_existing_clip_intact(tmp_path):
    clip = _clip()
    path = save_clip(clip, tmp_path / "keep.npz")
    before = path.read_bytes()

    broken = object.__new__(Clip)
    object.__setattr__(broken, "qpos", clip.qpos)
    object.__setattr__(broken, "qvel", "not an array")  # fails inside save_clip, after the temp file exists
    object.__setattr__(broken, "obs", clip.obs)
    for key in ("name", "source", "license", "fps"):
        object.__setattr__(broken, key, getattr(clip, key))
    with pytest.raises(AttributeError):
        save_clip(broken, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep.npz"]  # no temp file left behind
