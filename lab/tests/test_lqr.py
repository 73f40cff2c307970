"""Feedback around a demonstration: the linearisation is the env's physics, the error ignores heading and place,
the gains keep a perturbed start nearer its demonstration than replaying its actions does, and a library acts by
its nearest state."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from humanoid_env.env import HumanoidEnv
from humanoid_env.errors import EnvError
from lqr import (MAX_STEPS, FunnelLibrary, LqrCost, StabilisedTrajectory, align_heading, full_state,
                              match_features, stabilise, state_error, step_jacobians)
from humanoid_env.model import NU, NV, default_qpos


def standing_env() -> HumanoidEnv:
    env = HumanoidEnv(max_episode_steps=10**6)
    env.reset(options={"qpos": default_qpos(), "qvel": np.zeros(NV)})
    for _ in range(10):
        env.step(np.zeros(NU))
    return env


def turned(qpos: np.ndarray, qvel: np.ndarray, angle: float, shift: tuple[float, float]):
    """The same state turned about the vertical through the origin and moved."""
    q, v = qpos.copy(), qvel.copy()
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    q[0:2] = rot @ qpos[0:2] + np.asarray(shift)
    mujoco.mju_mulQuat(q[3:7], np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]), qpos[3:7].copy())
    v[0:2] = rot @ qvel[0:2]
    return q, v


def test_step_jacobians_predict_a_small_change_of_state_and_action():
    env = standing_env()
    state = full_state(env)
    action = np.full(NU, 0.05)
    A, B = step_jacobians(env, state, action)
    base_q, base_v = env.data.qpos.copy(), env.data.qvel.copy()

    # Contacts make the step smooth only very near the state (a 1e-4 change already switches some), so the
    # derivatives are checked at the scale they describe.
    rng = np.random.default_rng(0)
    dx, du = rng.normal(scale=1e-6, size=2 * NV), rng.normal(scale=1e-5, size=NU)
    mujoco.mj_setState(env.model, env.data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    mujoco.mj_integratePos(env.model, env.data.qpos, dx[:NV], 1.0)
    env.data.qvel[:] += dx[NV:]
    env.step(action + du)
    moved = np.zeros(NV)
    mujoco.mj_differentiatePos(env.model, moved, 1.0, base_q, env.data.qpos)
    actual = np.concatenate([moved, env.data.qvel - base_v])
    predicted = A @ dx + B @ du
    assert np.linalg.norm(actual - predicted) < 0.05 * np.linalg.norm(actual)
    assert np.linalg.norm(B @ du) > 0.3 * np.linalg.norm(actual)  # the action's part is not lost in the state's


def test_the_error_ignores_where_the_body_is_and_which_way_it_faces():
    env = standing_env()
    env.step(np.full(NU, 0.3))
    q, v = env.data.qpos.copy(), env.data.qvel.copy()
    q2, v2 = turned(q, v, 2.0, (1.5, -0.7))
    np.testing.assert_allclose(state_error(env.model, q2, v2, q, v), 0.0, atol=1e-9)
    aligned_q, aligned_v = align_heading(q2, v2, q)
    np.testing.assert_allclose(aligned_v, v, atol=1e-12)
    np.testing.assert_allclose(match_features(q2, v2), match_features(q, v), atol=1e-12)
    # a tilt is not a heading: it stays in the error
    tilted = q.copy()
    mujoco.mju_mulQuat(tilted[3:7], np.array([np.cos(0.1), np.sin(0.1), 0.0, 0.0]), q[3:7].copy())
    assert np.linalg.norm(state_error(env.model, tilted, v, q, v)[3:6]) > 0.15


@pytest.fixture(scope="module")
def squat() -> tuple[np.ndarray, np.ndarray, StabilisedTrajectory]:
    """A short knee bend and back from standing, and the feedback around it."""
    env = standing_env()
    q0, v0 = env.data.qpos.copy(), env.data.qvel.copy()
    bend = np.zeros(NU)
    knees = [i for i, name in enumerate(env.model.actuator(k).name for k in range(NU)) if "Knee" in name]
    hips = [i for i, name in enumerate(env.model.actuator(k).name for k in range(NU)) if "Hip" in name]
    bend[knees], bend[hips] = 0.5, -0.3
    depth = np.sin(np.linspace(0, np.pi, 24))[:, None]
    return q0, v0, stabilise(q0, v0, depth * bend)


def test_feedback_brings_a_pushed_start_back_to_its_demonstration_where_replaying_its_actions_drifts(squat):
    q0, v0, traj = squat
    model = HumanoidEnv(max_episode_steps=1).model
    env = HumanoidEnv(max_episode_steps=10**6)
    np.testing.assert_allclose(traj.qpos[0], q0)
    end_error = {}
    for feedback in (False, True):
        pushed = v0.copy()
        pushed[0:2] += (0.05, -0.04)
        env.reset(options={"qpos": q0, "qvel": pushed})
        for t, a in enumerate(traj.actions):
            if feedback:
                a = np.clip(a + traj.gains[t] @ state_error(model, env.data.qpos, env.data.qvel, traj.qpos[t],
                                                              traj.qvel[t]), -1, 1)
            env.step(a)
        end_error[feedback] = np.linalg.norm(state_error(model, env.data.qpos, env.data.qvel, traj.qpos[-1],
                                                         traj.qvel[-1])[:NV])
    assert end_error[True] < 0.5 * end_error[False]


def test_a_library_acts_by_its_nearest_state_and_hands_over_where_marked(squat, tmp_path):
    q0, v0, traj = squat
    path = traj.save(tmp_path / "squat.npz")
    lib = FunnelLibrary.load(tmp_path, tail=5)
    T = len(traj.actions)
    steps = np.array([0, 7, T - 6, T - 2])
    moved = [turned(traj.qpos[t], traj.qvel[t], -1.2 + t, (3.0, 2.0)) for t in steps]
    q, v = np.array([m[0] for m in moved]), np.array([m[1] for m in moved])
    np.testing.assert_array_equal(lib.nearest(q, v), steps)
    actions, handed = lib.act(q, v)
    np.testing.assert_array_equal(handed, [False, False, False, True])
    np.testing.assert_allclose(actions[:3], traj.actions[steps[:3]], atol=1e-6)
    np.testing.assert_array_equal(actions[3], 0.0)
    held = np.array([True, True, False, False])
    np.testing.assert_array_equal(lib.act(q, v, held, release=0.0)[1], [True, True, False, True])
    between = (q[0, 2] + q[1, 2]) / 2  # the lower of the two held bodies goes back to the library
    kept = lib.act(q, v, held, release=between)[1]
    np.testing.assert_array_equal(kept, [q[0, 2] > between, q[1, 2] > between, False, True])
    assert kept[:2].sum() == 1
    np.testing.assert_array_equal(lib.act(q, v, held, release=10.0)[1], handed)
    with pytest.raises(EnvError, match="held must be"):
        lib.act(q, v, held[:2])
    with pytest.raises(EnvError, match="release must be a finite pelvis height"):
        lib.act(q, v, held, release=float("nan"))

    marked = StabilisedTrajectory(traj.qpos, traj.qvel, traj.actions, traj.gains, handoff=np.arange(T) == 7)
    marked.save(path)
    loaded = StabilisedTrajectory.load(path)
    np.testing.assert_allclose(loaded.gains, traj.gains, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(FunnelLibrary([loaded]).act(q, v)[1], [False, True, False, False])


def test_bad_trajectories_costs_and_folders_are_named(squat, tmp_path):
    _, _, traj = squat
    bad = tmp_path / "bad.npz"
    np.savez(bad, qpos=traj.qpos, qvel=traj.qvel, actions=traj.actions[:-1], gains=traj.gains)
    with pytest.raises(EnvError, match="bad.npz: stabilised trajectory qpos must have shape"):
        StabilisedTrajectory.load(bad)
    gains = traj.gains.copy()
    gains[0, 0, 0] = np.nan
    with pytest.raises(EnvError, match="gains contains NaN"):
        StabilisedTrajectory(traj.qpos, traj.qvel, traj.actions, gains)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(EnvError, match="junk.npz: not a stabilised trajectory"):
        StabilisedTrajectory.load(tmp_path / "junk.npz")
    library = FunnelLibrary([traj])
    with pytest.raises(EnvError, match="funnel library states must be finite qpos"):
        library.act(traj.qpos[:2], traj.qvel[:3])
    with pytest.raises(EnvError, match="funnel library states must be finite qpos"):
        library.act(np.full((1, 76), np.nan), traj.qvel[:1])
    with pytest.raises(EnvError, match="no stabilised trajectories"):
        FunnelLibrary.load(tmp_path / "empty")
    with pytest.raises(EnvError, match="LQR cost weights"):
        LqrCost(w_action=0.0)
    with pytest.raises(EnvError, match="handoff must have shape"):
        StabilisedTrajectory(traj.qpos, traj.qvel, traj.actions, traj.gains, handoff=np.zeros(3, bool))
    long = tmp_path / "long.npz"
    np.savez(long, actions=np.zeros((MAX_STEPS + 1, NU)), gains=np.zeros(1))
    with pytest.raises(EnvError, match=f"long.npz: {MAX_STEPS + 1} steps, over the limit"):
        StabilisedTrajectory.load(long)
    with pytest.raises(EnvError, match="actions must be finite"):
        stabilise(traj.qpos[0], traj.qvel[0], np.full((3, NU), np.nan))
