"""The batched humanoid env: bit-identical physics, SAME_STEP autoreset, divergence handling."""
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from humanoid_env.env import FALLEN_HEIGHT, HumanoidEnv
from humanoid_env.errors import EnvError
from humanoid_env.inits import DefaultInit, FallInit, make_init
from humanoid_env.model import NQ, NV
from humanoid_env.observation import observe
from humanoid_env.vector import VectorHumanoidEnv


def _actions(seed, steps, n):
    return np.random.default_rng(seed).uniform(-1, 1, (steps, n, 69)).astype(np.float32)


def _rollout(env, seed, steps=12):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in _actions(seed, steps, env.num_envs):
        out.append(env.step(a)[0])
    return np.stack(out)


def test_spaces_and_metadata():
    env = VectorHumanoidEnv(3, num_threads=1)
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert env.observation_space.shape == (3, 358) and env.action_space.shape == (3, 69)
    assert env.single_observation_space.shape == (358,) and env.single_action_space.shape == (69,)
    obs, info = env.reset(seed=0)
    assert obs.shape == (3, 358) and obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert info["qpos"].shape == (3, NQ) and info["qvel"].shape == (3, NV)
    with pytest.raises(ValueError, match="actions"):
        env.step(np.zeros((2, 69)))
    bad = np.zeros((3, 69))
    bad[2, 5] = np.nan
    with pytest.raises(ValueError, match=r"NaN or inf \(envs \[2\]\)"):
        env.step(bad)
    with pytest.raises(ValueError, match="num_envs"):
        VectorHumanoidEnv(0)


def test_matches_single_env_bit_for_bit():
    n, steps = 3, 10
    venv = VectorHumanoidEnv(n, init=FallInit(), num_threads=2, max_episode_steps=100)
    obs, info = venv.reset(seed=5)
    acts = _actions(0, steps, n)
    vobs = [obs]
    for a in acts:
        vobs.append(venv.step(a)[0])
    single = HumanoidEnv(max_episode_steps=100)
    for i in range(n):
        o, _ = single.reset(options={"qpos": info["qpos"][i], "qvel": info["qvel"][i]})
        traj = [o] + [single.step(a[i])[0] for a in acts]
        np.testing.assert_array_equal(np.stack(traj), np.stack(vobs)[:, i])


def test_same_seed_same_rollout_any_thread_count():
    a = _rollout(VectorHumanoidEnv(4, init=make_init(0.5), num_threads=1, max_episode_steps=5), seed=2)
    b = _rollout(VectorHumanoidEnv(4, init=make_init(0.5), num_threads=2, max_episode_steps=5), seed=2)
    np.testing.assert_array_equal(a, b)  # includes two autoresets drawn from the seeded generator
    c = _rollout(VectorHumanoidEnv(4, init=make_init(0.5), num_threads=2, max_episode_steps=5), seed=3)
    assert np.abs(a - c).max() > 1e-2


def test_same_step_autoreset():
    env = VectorHumanoidEnv(2, max_episode_steps=3, num_threads=1)
    env.reset(seed=0)
    zero = np.zeros((2, 69), np.float32)
    for _ in range(2):
        obs, _, term, trunc, info = env.step(zero)
        assert not (term | trunc).any() and not info["_final_obs"].any()
        np.testing.assert_array_equal(info["final_obs"], obs)
    obs, _, term, trunc, info = env.step(zero)
    assert trunc.all() and not term.any() and info["_final_obs"].all()
    # the returned observation is the new episode's first; final_* hold the state the step reached
    np.testing.assert_allclose(info["final_obs"], observe(env.model, info["final_qpos"], info["final_qvel"]), atol=1e-6)
    np.testing.assert_allclose(obs, observe(env.model, info["qpos"], info["qvel"]), atol=1e-6)
    assert np.abs(info["final_obs"] - obs).max() > 1e-3
    obs2, _, _, trunc, info = env.step(zero)
    assert not trunc.any()  # the step counter restarted


def test_reset_options_exact_state():
    env = VectorHumanoidEnv(2, num_threads=1)
    qpos, qvel = FallInit().sample(np.random.default_rng(0), 2)
    obs, info = env.reset(options={"qpos": qpos, "qvel": qvel})
    np.testing.assert_array_equal(info["qpos"], qpos)
    np.testing.assert_array_equal(info["qvel"], qvel)
    np.testing.assert_allclose(obs, observe(env.model, qpos, qvel), atol=1e-6)
    with pytest.raises(ValueError, match="qpos"):
        env.reset(options={"qpos": qpos[:1], "qvel": qvel[:1]})
    with pytest.raises(ValueError, match="NaN"):
        env.reset(options={"qpos": qpos * np.nan, "qvel": qvel})


@pytest.mark.parametrize("bad", [1e9, np.nan])
def test_divergence_in_one_env(bad):
    seen = []
    env = VectorHumanoidEnv(3, num_threads=2, reward=lambda o, a, q, v: seen.append(o.shape) or o[:, 0])
    obs0, _ = env.reset(seed=0)
    env._qvel[1, 12] = bad  # inject into env 1's simulation state
    obs, reward, term, trunc, info = env.step(np.zeros((3, 69), np.float32))
    assert info["diverged"].tolist() == [False, True, False] and term.tolist() == [False, True, False]
    assert np.isfinite(obs).all() and np.isfinite(info["final_obs"]).all() and np.isfinite(info["final_qvel"]).all()
    np.testing.assert_array_equal(info["final_obs"][1], obs0[1])  # last good observation
    assert reward[1] == 0.0 and reward[0] == pytest.approx(obs[0, 0]) and seen == [(3, 358)]
    np.testing.assert_allclose(obs[1], observe(env.model, info["qpos"][1], info["qvel"][1]), atol=1e-6)  # reset
    obs, _, term, _, info = env.step(np.zeros((3, 69), np.float32))
    assert not info["diverged"].any() and not term.any()


def test_termination_fn_resets_those_envs():
    env = VectorHumanoidEnv(2, num_threads=1, termination=lambda o, q, v: np.array([True, False]))
    env.reset(seed=0)
    _, _, term, trunc, info = env.step(np.zeros((2, 69), np.float32))
    assert term.tolist() == [True, False] and info["_final_obs"].tolist() == [True, False]


def test_reward_by_task_name():
    env = VectorHumanoidEnv(2, num_threads=1, reward="raisearms-l-l")  # resolved through humanoid_env.tasks
    env.reset(seed=0)
    _, reward, _, _, _ = env.step(np.zeros((2, 69), np.float32))
    assert reward.shape == (2,) and ((reward >= 0) & (reward <= 1)).all()
    with pytest.raises(ValueError, match="unknown reward"):
        VectorHumanoidEnv(1, reward="no-such-task")


def _first_run_end(heights, k):
    """Index of the step at which the pelvis has been below the fallen line k steps in a row (None: never)."""
    run = 0
    for t, h in enumerate(heights):
        run = run + 1 if h < FALLEN_HEIGHT else 0
        if run == k:
            return t
    return None


def _standing_and_fallen(standing, steps):
    """A start of two envs (a `standing` init's state, a fall state) and their pelvis heights (steps, 2) under
    zero actions with no reset on a fall."""
    qs, vs = standing.sample(np.random.default_rng(0), 1)
    qf, vf = FallInit().sample(np.random.default_rng(1), 1)
    start = {"qpos": np.concatenate([qs, qf]), "qvel": np.concatenate([vs, vf])}
    free = VectorHumanoidEnv(2, num_threads=1, max_episode_steps=steps + 1)
    free.reset(options=start)
    zero = np.zeros((2, 69), np.float32)
    return start, np.stack([free.step(zero)[4]["final_qpos"][:, 2] for _ in range(steps)])


def test_reset_fallen_after_truncates_lying_envs_only():
    zero, steps, k = np.zeros((2, 69), np.float32), 60, 7
    start, heights = _standing_and_fallen(DefaultInit(), steps)
    qf, vf = start["qpos"][1:], start["qvel"][1:]
    end = _first_run_end(heights[:, 1], k)
    assert _first_run_end(heights[:, 0], 1) is None and end is not None  # one stands, the other lies

    env = VectorHumanoidEnv(2, num_threads=1, max_episode_steps=steps + 1, reset_fallen_after=k)
    env.reset(options=start)
    terms, truncs = map(np.stack, zip(*[env.step(zero)[2:4] for _ in range(end + 1)]))
    assert not truncs[:, 0].any() and np.flatnonzero(truncs[:, 1]).tolist() == [end] and not terms.any()
    env = VectorHumanoidEnv(2, num_threads=1, max_episode_steps=steps + 1, reset_fallen_after=k, fallen_terminates=True)
    env.reset(options=start)
    terms, truncs = map(np.stack, zip(*[env.step(zero)[2:4] for _ in range(end + 1)]))
    assert not terms[:, 0].any() and np.flatnonzero(terms[:, 1]).tolist() == [end] and not truncs.any()

    single = HumanoidEnv(max_episode_steps=steps + 1, reset_fallen_after=k)
    single.reset(options={"qpos": qf[0], "qvel": vf[0]})
    assert [single.step(zero[0])[3] for _ in range(end + 1)].index(True) == end
    single = HumanoidEnv(max_episode_steps=steps + 1, reset_fallen_after=k, fallen_terminates=True)
    single.reset(options={"qpos": qf[0], "qvel": vf[0]})
    assert [single.step(zero[0])[2] for _ in range(end + 1)].index(True) == end


def test_reset_fallen_once_up_spares_a_fall_start_until_it_has_been_up():
    """A pushed standing start is up for k steps before it falls, so its clock runs; a fall start never was."""
    zero, steps, k = np.zeros((2, 69), np.float32), 120, 7
    start, heights = _standing_and_fallen(DefaultInit(0.1, 0.3), steps)
    pushed, lying = _first_run_end(heights[:, 0], k), _first_run_end(heights[:, 1], k)
    assert pushed is not None and pushed > 2 * k and lying is not None and lying < pushed  # both fall, one was up

    env = VectorHumanoidEnv(2, num_threads=1, max_episode_steps=steps + 1, reset_fallen_after=k, reset_fallen_once_up=True)
    env.reset(options=start)
    truncs = np.stack([env.step(zero)[3] for _ in range(pushed + 1)])
    assert np.flatnonzero(truncs[:, 0]).tolist() == [pushed] and not truncs[:, 1].any()
    for col in (0, 1):
        single = HumanoidEnv(max_episode_steps=steps + 1, reset_fallen_after=k, reset_fallen_once_up=True)
        single.reset(options={"qpos": start["qpos"][col], "qvel": start["qvel"][col]})
        assert [single.step(zero[0])[3] for _ in range(pushed + 1)] == truncs[:, col].tolist()


@pytest.mark.parametrize("bad", [-1, 1.5, True])
def test_reset_fallen_after_rejects_bad_values(bad):
    with pytest.raises(EnvError, match="reset_fallen_after"):
        VectorHumanoidEnv(1, reset_fallen_after=bad)
    with pytest.raises(EnvError, match="reset_fallen_after"):
        HumanoidEnv(reset_fallen_after=bad)


@pytest.mark.parametrize("seconds, steps", [(0.0, 0), (0.5, 15), (0.01, 1)])
def test_config_reset_fallen_s_reaches_the_training_env_only(seconds, steps):
    from fbcpr.core.schema import EnvConfig
    from fbcpr.envs.bundle import make_env

    bundle = make_env(EnvConfig(name="humanoid", reset_fallen_s=seconds), 1, 0)
    assert bundle.env.reset_fallen_after == steps
    assert bundle.make_eval_env(1, 10).reset_fallen_after == 0  # evaluation episodes run their full length
