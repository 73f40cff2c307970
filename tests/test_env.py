"""The single-humanoid Gymnasium env, its init samplers and rendering."""
import os
import subprocess
import sys
import warnings

from humanoid_env import ENV_ID  # first: it picks the headless GL backend before mujoco is imported

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from humanoid_env.env import HumanoidEnv
from humanoid_env.actions import ActionMap
from humanoid_env.inits import DefaultInit, FallInit, FixedStates, MixtureInit, MocapInit, _Geometry, make_init
from humanoid_env.model import JOINT_NAMES, NQ, NV, joint_ranges, load_model
from humanoid_env.observation import observe


def _pose_action(model, angles: np.ndarray) -> np.ndarray:
    return ActionMap(model).from_angles(angles)


def _floor_contacts(model, qpos) -> int:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    return sum(1 for c in data.contact[: data.ncon] if 0 in (c.geom1, c.geom2)) if data.ncon else 0


def test_gymnasium_env_checker_and_registration():
    env = gym.make(ENV_ID)
    assert env.observation_space.shape == (358,) and env.observation_space.dtype == np.float32
    assert env.action_space.shape == (69,) and (env.action_space.low == -1).all() and (env.action_space.high == 1).all()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # only the unbounded-Box notices; failures raise
        check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_observation_matches_kinematic_function():
    env = HumanoidEnv()
    rng = np.random.default_rng(0)
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(obs, observe(env.model, info["qpos"], info["qvel"]))
    for _ in range(10):
        obs, _, _, _, info = env.step(rng.uniform(-1, 1, 69).astype(np.float32))
    assert obs.dtype == np.float32 and obs.shape == (358,)
    np.testing.assert_allclose(obs, observe(env.model, info["qpos"], info["qvel"]), atol=1e-6)
    assert info["qpos"] is not env.data.qpos and not np.shares_memory(info["qpos"], env.data.qpos)


def test_reset_options_set_exact_state_and_reject_bad_input():
    env = HumanoidEnv()
    qpos, qvel = FallInit().sample(np.random.default_rng(1), 1)
    obs, info = env.reset(options={"qpos": qpos[0], "qvel": qvel[0] + 0.1})
    np.testing.assert_array_equal(info["qpos"], qpos[0])
    np.testing.assert_array_equal(info["qvel"], qvel[0] + 0.1)
    np.testing.assert_array_equal(obs, observe(env.model, qpos[0], qvel[0] + 0.1))
    with pytest.raises(ValueError, match="qpos"):
        env.reset(options={"qpos": np.zeros(75), "qvel": np.zeros(NV)})
    with pytest.raises(ValueError, match="NaN"):
        env.reset(options={"qpos": np.full(NQ, np.nan), "qvel": np.zeros(NV)})
    with pytest.raises(ValueError, match="both"):
        env.reset(options={"qpos": qpos[0]})
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(68))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(69, np.nan))


def test_pd_holds_tpose_and_reaches_arm_targets():
    env = HumanoidEnv(max_episode_steps=1000)
    env.reset(seed=0)
    hold = _pose_action(env.model, np.zeros(69))
    for _ in range(60):  # 2 s holding the T-pose
        _, _, terminated, _, info = env.step(hold)
        assert not terminated
        assert np.degrees(np.abs(info["qpos"][7:])).max() < 6.0
    assert info["qpos"][2] > 0.9  # still standing

    idx = {n: i for i, n in enumerate(JOINT_NAMES)}
    target = np.zeros(69)
    arms = [idx["L_Shoulder_x"], idx["R_Shoulder_x"], idx["L_Elbow_z"], idx["R_Elbow_z"]]
    target[arms] = np.radians([-60.0, 60.0, -60.0, 60.0])
    before = np.degrees(np.abs(info["qpos"][7:][arms] - target[arms]))
    for _ in range(30):
        _, _, _, _, info = env.step(_pose_action(env.model, target))
    after = np.degrees(np.abs(info["qpos"][7:][arms] - target[arms]))
    assert before.min() > 50 and after.max() < 3.0, (before, after)


def test_same_seed_same_rollout():
    def rollout(seed):
        env = HumanoidEnv(init=make_init(0.5))
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        out = [obs]
        for _ in range(15):
            out.append(env.step(rng.uniform(-1, 1, 69).astype(np.float32))[0])
        return np.stack(out)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert np.abs(rollout(3) - rollout(4)).max() > 1e-2


def test_divergence_mid_episode():
    env = HumanoidEnv()
    env.reset(seed=0)
    for _ in range(5):
        obs, _, _, _, info = env.step(np.zeros(69, np.float32))
    env.data.qvel[30] = 1e12
    obs2, _, terminated, _, info2 = env.step(np.zeros(69, np.float32))
    assert terminated and info2["diverged"]
    np.testing.assert_array_equal(obs2, obs)
    np.testing.assert_array_equal(info2["qvel"], info["qvel"])


@pytest.mark.parametrize("bad", [1e9, np.nan])
def test_divergence_is_reported_and_recovered(bad):
    env = HumanoidEnv()
    obs0, info0 = env.reset(seed=0)
    env.data.qvel[12] = bad  # inject: a blown-up joint velocity
    obs, reward, terminated, truncated, info = env.step(np.zeros(69, np.float32))
    assert info["diverged"] and terminated and reward == 0.0
    assert np.isfinite(obs).all() and np.isfinite(info["qpos"]).all() and np.isfinite(info["qvel"]).all()
    np.testing.assert_array_equal(obs, obs0)  # the last good observation, and its state
    np.testing.assert_array_equal(info["qpos"], info0["qpos"])
    obs, info = env.reset(seed=1)
    obs, _, terminated, _, info = env.step(np.zeros(69, np.float32))
    assert not info["diverged"] and not terminated and np.isfinite(obs).all()


def test_velocity_threshold_counts_as_divergence():
    env = HumanoidEnv(max_qvel=0.5)
    qpos, qvel = DefaultInit(0.0, 0.0).sample(np.random.default_rng(0), 1)
    qvel[0, 0] = 3.0  # root sliding at 3 m/s: over this env's threshold
    env.reset(options={"qpos": qpos[0], "qvel": qvel[0]})
    _, _, terminated, _, info = env.step(np.zeros(69, np.float32))
    assert terminated and info["diverged"]


def test_reward_termination_and_truncation():
    seen = {}

    def reward(obs, action, qpos, qvel):
        seen.update(obs=obs.shape, action=action.shape, qpos=qpos.shape, qvel=qvel.shape)
        return obs[:, 0]  # root height

    env = HumanoidEnv(reward=reward, max_episode_steps=3)
    env.reset(seed=0)
    obs, r, terminated, truncated, _ = env.step(np.zeros(69, np.float32))
    assert seen == {"obs": (1, 358), "action": (1, 69), "qpos": (1, NQ), "qvel": (1, NV)}
    assert r == pytest.approx(float(obs[0])) and not terminated and not truncated
    env.step(np.zeros(69, np.float32))
    assert env.step(np.zeros(69, np.float32))[3]  # truncated at step 3

    low = HumanoidEnv(termination=lambda obs, qpos, qvel: obs[:, 0] < 2.0)
    low.reset(seed=0)
    assert low.step(np.zeros(69, np.float32))[2]
    with pytest.raises(TypeError, match="reward"):
        HumanoidEnv(reward=3)


def test_default_init_stands_on_floor():
    model = load_model()
    qpos, qvel = DefaultInit().sample(np.random.default_rng(0), 8)
    assert qpos.shape == (8, NQ) and qvel.shape == (8, NV)
    rng_ = joint_ranges()
    assert (np.abs(qpos[:, 7:]) <= 0.02 + 1e-12).all()
    assert ((qpos[:, 7:] >= rng_[:, 0]) & (qpos[:, 7:] <= rng_[:, 1])).all()
    low = _Geometry().lowest_z(qpos)
    assert (low > -1e-9).all() and (low < 0.02).all()


def test_fall_init_is_random_above_floor_and_stable():
    model = load_model()
    init = FallInit(height=(0.2, 0.6))
    qpos, qvel = init.sample(np.random.default_rng(0), 16)
    lo, hi = joint_ranges()[:, 0], joint_ranges()[:, 1]
    assert ((qpos[:, 7:] >= lo) & (qpos[:, 7:] <= hi)).all()
    np.testing.assert_allclose(np.linalg.norm(qpos[:, 3:7], axis=1), 1.0)
    assert np.std(qpos[:, 3:7], axis=0).min() > 0.2  # orientations are spread out
    geo = _Geometry()
    low = geo.lowest_z(qpos)
    assert ((low > 0.2 - 1e-9) & (low < 0.6 + 1e-9)).all()
    assert all(_floor_contacts(model, q) == 0 for q in qpos)
    assert geo.self_penetration(qpos).max() <= 0.01
    env = HumanoidEnv(init=init)
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(30):  # falls and lands without blowing up
            obs, _, terminated, _, info = env.step(np.zeros(69, np.float32))
            assert not info["diverged"]
        assert info["qpos"][2] < 0.5


class _Library:
    """A stand-in motion library with the `sample_states` interface."""

    def __init__(self, shape_ok=True):
        self.shape_ok = shape_ok

    def sample_states(self, rng, n):
        qpos = np.tile(load_model().qpos0, (n, 1))
        qpos[:, 0] = rng.uniform(5, 6, n)
        return (qpos if self.shape_ok else qpos[:, :-1]), np.zeros((n, NV))


def test_mocap_and_mixture_inits():
    rng = np.random.default_rng(0)
    qpos, _ = MocapInit(_Library()).sample(rng, 5)
    assert (qpos[:, 0] >= 5).all()
    with pytest.raises(ValueError, match="motion library"):
        MocapInit(_Library(shape_ok=False)).sample(rng, 2)
    with pytest.raises(TypeError, match="sample_states"):
        MocapInit(object())
    mix = make_init(0.25, mocap=_Library())
    qpos, _ = mix.sample(rng, 400)
    from_mocap = qpos[:, 0] >= 5
    assert 0.15 < 1 - from_mocap.mean() < 0.35
    assert (make_init(1.0).sample(rng, 4)[0][:, 3] < 0.999).all()  # all falls: tilted roots
    with pytest.raises(ValueError, match="fall_prob"):
        make_init(1.5)
    qpos, _ = make_init(0.2, mocap=_Library(), stand_prob=0.5).sample(rng, 400)
    standing = np.all(np.abs(qpos[:, 3:7] - [1, 0, 0, 0]) < 1e-9, axis=1) & (qpos[:, 0] < 5)  # upright root, not MoCap
    assert 0.4 < standing.mean() < 0.6 and 0.2 < (qpos[:, 0] >= 5).mean() < 0.4
    with pytest.raises(ValueError, match="stand_prob"):
        make_init(0.5, stand_prob=0.6)
    with pytest.raises(ValueError, match="focus_prob"):
        make_init(0.5, stand_prob=0.3, focus=_Library(), focus_prob=0.3)
    with pytest.raises(ValueError, match="focus state source"):
        make_init(0.5, focus_prob=0.3)
    with pytest.raises(ValueError, match="weight"):
        MixtureInit([DefaultInit()], [-1.0])


def test_fixed_states_come_in_order_and_repeat_to_fill_a_batch():
    qpos, qvel = np.tile(load_model().qpos0, (3, 1)), np.zeros((3, NV))
    qpos[:, 0], qvel[:, 0] = [1.0, 2.0, 3.0], [0.1, 0.2, 0.3]
    init = FixedStates(qpos, qvel)
    q, v = init.sample(np.random.default_rng(0), 7)
    np.testing.assert_array_equal(q[:, 0], [1, 2, 3, 1, 2, 3, 1])
    np.testing.assert_array_equal(v[:, 0], [0.1, 0.2, 0.3, 0.1, 0.2, 0.3, 0.1])
    q[:] = 0.0                                                   # the caller's copy, not the source's
    assert init.sample(np.random.default_rng(0), 1)[0][0, 0] == 1.0
    with pytest.raises(ValueError, match=r"FixedStates needs qpos \(k, 76\)"):
        FixedStates(qpos[:, :-1], qvel)
    with pytest.raises(ValueError, match="k >= 1"):
        FixedStates(qpos[:0], qvel[:0])


def test_rendering_and_video(tmp_path):
    from humanoid_env.render import renderer_available, write_video

    with pytest.raises(ValueError, match="frames"):
        write_video([], tmp_path / "empty.mp4")
    if not renderer_available():
        pytest.skip("no OpenGL renderer in this process (MUJOCO_GL)")
    env = HumanoidEnv(render_mode="rgb_array", width=160, height=128)
    env.reset(seed=0)
    frames = [env.render()]
    for _ in range(5):
        env.step(np.zeros(69, np.float32))
        frames.append(env.render())
    assert frames[0].shape == (128, 160, 3) and frames[0].dtype == np.uint8
    assert frames[0].std() > 5  # a scene, not a blank buffer
    path = write_video(frames, tmp_path / "roll.mp4")
    import imageio.v3 as iio

    back = list(iio.imiter(path))
    assert len(back) == len(frames) and back[0].shape == (128, 160, 3)
    env.close()


def test_rendering_error_names_mujoco_gl():
    code = (
        "from humanoid_env.env import HumanoidEnv\n"
        "env = HumanoidEnv(render_mode='rgb_array'); env.reset(seed=0)\n"
        "try:\n    env.render(); print('RENDERED')\n"
        "except RuntimeError as e:\n    print('ERROR', e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    env["MUJOCO_GL"] = "glfw"  # a windowing backend without a display
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert run.stdout.startswith("RENDERED") or ("ERROR" in run.stdout and "MUJOCO_GL=glfw" in run.stdout), run.stdout + run.stderr


def test_rollout_command_prints_stats():
    from typer.testing import CliRunner

    from fbcpr.cli.app import app

    result = CliRunner().invoke(app, ["rollout", "--steps", "20", "--policy", "random", "--seed", "1"])
    assert result.exit_code == 0, result.output
    assert "steps/s" in result.output and "diverged" in result.output and "20" in result.output
    bad = CliRunner().invoke(app, ["rollout", "--policy", "fast"])
    assert bad.exit_code != 0


@pytest.mark.parametrize("mapping", ["rest", "mid"])
def test_action_mapping_round_trip_and_range(mapping):
    model = load_model()
    amap = ActionMap(model, mapping)
    lo, hi = model.actuator_ctrlrange.T
    assert np.allclose(amap.to_ctrl(np.full(69, -1.0)), lo) and np.allclose(amap.to_ctrl(np.ones(69)), hi)
    angles = np.random.default_rng(0).uniform(lo, hi)
    assert np.allclose(amap.to_ctrl(amap.from_angles(angles).astype(np.float64)), angles, atol=1e-5)
    rest = amap.to_ctrl(np.zeros(69))
    assert np.allclose(rest, 0.0) if mapping == "rest" else np.allclose(rest, (lo + hi) / 2)


def test_zero_action_stands_under_rest_mapping_and_falls_under_mid():
    heights = {}
    for mapping in ("rest", "mid"):
        env = HumanoidEnv(max_episode_steps=100, action_mapping=mapping)
        env.reset(seed=0)
        for _ in range(90):  # 3 s
            obs, *_ = env.step(np.zeros(69, np.float32))
        heights[mapping] = obs[0]
    assert heights["rest"] > 0.8 and heights["mid"] < 0.6, heights


def test_unknown_action_mapping_is_rejected():
    with pytest.raises(ValueError, match="action_mapping"):
        HumanoidEnv(action_mapping="crouch")
