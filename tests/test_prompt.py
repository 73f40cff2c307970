"""Prompt layer: every z against the paper's formula computed by hand on a tiny model, plus bad prompts."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import humanoid_states
from fbcpr.inference.bfm import BFM
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.core.errors import PromptError
from fbcpr.inference.prompt import goal_reward
from fbcpr.inference.timeline import Timeline, parse_timeline
from humanoid_env.model import NV, load_model
from humanoid_env.observation import observe
from humanoid_env.tasks import get_reward
from humanoid_env.tasks.goals import goal_obs, goal_qpos

torch.set_num_threads(1)
SEQ = 4


@pytest.fixture(scope="module")
def bfm() -> BFM:
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": SEQ, "batch_size": 8}})
    model = FBCPRModel(cfg.model)
    states = humanoid_states(200, seed=1)
    model.obs_normalizer.update(torch.as_tensor(states["next_obs"]))  # non-trivial normalization, as after training
    return BFM(model, cfg, reward_buffer=states)


def b_by_hand(bfm: BFM, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        m = bfm.model
        return m.backward_map(m.normalize(torch.as_tensor(obs, dtype=torch.float32))).double().numpy()


def sphere(z: np.ndarray) -> np.ndarray:
    return np.sqrt(z.shape[-1]) * z / np.linalg.norm(z, axis=-1, keepdims=True)


def test_goal_z_is_normalized_b_of_goal(bfm):
    expected = sphere(b_by_hand(bfm, goal_obs("t_pose")[None])[0])
    np.testing.assert_allclose(bfm.prompt.goal("t_pose"), expected, rtol=1e-5, atol=1e-5)
    # a pose given as qpos gets zero velocities: same z as the named goal
    np.testing.assert_allclose(bfm.prompt.goal(goal_qpos("t_pose")), expected, rtol=1e-5, atol=1e-5)
    # a full observation is used as is: its velocities matter
    obs = observe(load_model(), goal_qpos("t_pose"), np.full(NV, 0.5))
    np.testing.assert_allclose(bfm.prompt.goal(obs), sphere(b_by_hand(bfm, obs[None])[0]), rtol=1e-5, atol=1e-5)
    assert np.linalg.norm(expected - bfm.prompt.goal(obs)) > 1e-3


def test_goal_from_states_is_the_weighted_regression_of_the_goal_proximity(bfm):
    from fbcpr.metrics import d_smpl

    buf, goal = bfm.reward_buffer, goal_obs("t_pose")
    r = np.exp(-d_smpl(buf["next_obs"], goal) / 2.0)
    assert 0 < r.min() < r.max() <= 1
    b = b_by_hand(bfm, buf["next_obs"])
    states = sphere((np.exp(10 * (r - r.max())) * r) @ b)
    np.testing.assert_allclose(bfm.prompt.goal("t_pose", method="states"), states, rtol=1e-4, atol=1e-4)
    pose = sphere(b_by_hand(bfm, goal[None])[0])
    np.testing.assert_allclose(bfm.prompt.goal("t_pose", method="mix"), sphere(pose + states), rtol=1e-4, atol=1e-4)
    assert np.linalg.norm(states - pose) > 1e-2  # B(g) and the states' z are different prompts
    # the package's goal reward is the formula above, and it peaks at the goal itself
    np.testing.assert_allclose(goal_reward(goal)(buf["next_obs"]), r, rtol=1e-12)
    assert goal_reward(goal)(goal[None])[0] == 1.0


def test_goal_methods_that_need_states_say_so_without_a_buffer(bfm):
    bare = BFM(bfm.model, bfm.config)
    for method in ("states", "mix"):
        with pytest.raises(PromptError, match=f"goal method '{method}'.*reward-inference buffer"):
            bare.prompt.goal("t_pose", method=method)
    with pytest.raises(PromptError, match="unknown goal inference method 'nearest'"):
        bfm.prompt.goal("t_pose", method="nearest")


def test_tracking_z_is_the_windowed_mean(bfm):
    obs = humanoid_states(11, seed=2)["next_obs"]
    zs = bfm.prompt.track(obs)
    b = b_by_hand(bfm, obs)
    assert zs.shape == (10, bfm.z_dim)
    for t in range(10):
        window = b[t + 1: min(t + 1 + SEQ, 11)]  # s_{t+1} .. s_{t+L}, clipped at the clip end
        np.testing.assert_allclose(zs[t], sphere(window.mean(0)), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(zs, axis=1), np.sqrt(bfm.z_dim), rtol=1e-5)


def test_imitate_is_er_fb_of_the_whole_clip(bfm):
    obs = humanoid_states(7, seed=3)["next_obs"]
    np.testing.assert_allclose(bfm.prompt.imitate(obs), sphere(b_by_hand(bfm, obs).mean(0)), rtol=1e-4, atol=1e-4)


def test_weighted_reward_regression_matches_formula(bfm):
    buf = bfm.reward_buffer
    r = get_reward("crouch-0")(buf["next_obs"], None, buf["qpos"], buf["qvel"]).astype(np.float64)
    assert r.max() > 0 and r.std() > 0
    b = b_by_hand(bfm, buf["next_obs"])
    weighted = sphere((np.exp(10 * r) * r) @ b)
    plain = sphere(r @ b)
    np.testing.assert_allclose(bfm.prompt.reward("crouch-0"), weighted, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(bfm.prompt.reward("crouch-0", method="regression"), plain, rtol=1e-4, atol=1e-4)


def test_weighted_regression_focuses_on_the_best_states(bfm):
    """A reward of 1 on one state and 0.5 elsewhere: exp(10 r) makes that state dominate the weighted z."""
    best = 17

    def reward(obs, action, qpos, qvel):
        r = np.full(len(obs), 0.5)
        r[best] = 1.0
        return r

    target = sphere(b_by_hand(bfm, bfm.reward_buffer["next_obs"][best][None])[0])
    cos = lambda z: float(z @ target) / bfm.z_dim  # noqa: E731
    assert cos(bfm.prompt.reward(reward)) > cos(bfm.prompt.reward(reward, method="regression")) + 0.05


def test_reward_subsample_is_seeded_and_capped(bfm):
    z1, z2 = bfm.prompt.reward("move-ego-0-0", n=50, seed=3), bfm.prompt.reward("move-ego-0-0", n=50, seed=3)
    np.testing.assert_array_equal(z1, z2)
    assert np.linalg.norm(z1 - bfm.prompt.reward("move-ego-0-0", n=50, seed=4)) > 1e-4
    buf = bfm.reward_buffer
    idx = np.sort(np.random.default_rng(3).choice(len(buf["next_obs"]), 50, replace=False))
    r = get_reward("move-ego-0-0")(buf["next_obs"][idx], None, buf["qpos"][idx], buf["qvel"][idx]).astype(np.float64)
    expected = sphere((np.exp(10 * r) * r) @ b_by_hand(bfm, buf["next_obs"][idx]))
    np.testing.assert_allclose(z1, expected, rtol=1e-4, atol=1e-4)


def test_combined_rewards_are_combined_before_inference(bfm):
    buf = bfm.reward_buffer
    r = get_reward("crouch-0")(buf["next_obs"], None, buf["qpos"], buf["qvel"]) * \
        get_reward("raisearms-l-l")(buf["next_obs"], None, buf["qpos"], buf["qvel"])
    expected = sphere((np.exp(10 * r) * r) @ b_by_hand(bfm, buf["next_obs"]))
    np.testing.assert_allclose(bfm.prompt.reward("crouch-0*raisearms-l-l"), expected, rtol=1e-4, atol=1e-4)


def test_mix_is_a_projected_weighted_sum(bfm):
    a, b = bfm.prompt.goal("t_pose"), bfm.prompt.goal("sit_on_ground")
    np.testing.assert_allclose(bfm.prompt.mix([(a, 1.0), (b, 0.0)]), a, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(bfm.prompt.mix([(a, 0.3), (torch.as_tensor(b), 0.7)]), sphere(0.3 * a + 0.7 * b),
                               rtol=1e-5, atol=1e-5)
    with pytest.raises(PromptError, match="zero"):
        bfm.prompt.mix([(a, 1.0), (a, -1.0)])


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda p: p.reward("fly-to-moon"), "unknown reward task 'fly-to-moon'"),
        (lambda p: p.reward("jump-2", method="magic"), "unknown reward inference method"),
        (lambda p: p.reward(lambda o, a, q, v: np.zeros(len(o))), "zero on all"),
        (lambda p: p.reward(lambda o, a, q, v: np.zeros(3)), "returned shape"),
        (lambda p: p.reward(lambda o, a, q, v: np.full(len(o), np.nan)), "non-finite"),
        (lambda p: p.goal("no_such_pose"), "unknown goal 'no_such_pose'"),
        (lambda p: p.goal(np.zeros(100)), r"got shape \(100,\)"),
        (lambda p: p.track(np.zeros((1, 358), np.float32)), "clip too short"),
        (lambda p: p.track(np.zeros((5, 300), np.float32)), r"\(T, 358\)"),
        (lambda p: p.track(np.full((5, 358), np.nan, np.float32)), "NaN"),
        (lambda p: p.track("/nonexistent/clip.npz"), "motion clip not found"),
        (lambda p: p.mix([(np.ones(3), 1.0)]), "shape"),
    ],
)
def test_bad_prompts_give_clear_errors(bfm, call, match):
    with pytest.raises(PromptError, match=match):
        call(bfm.prompt)


def test_reward_prompt_without_buffer_says_so(bfm):
    bare = BFM(bfm.model, bfm.config)
    with pytest.raises(PromptError, match="no reward-inference buffer"):
        bare.prompt.reward("jump-2")
    assert bare.prompt.goal("t_pose").shape == (bfm.z_dim,)  # other prompts still work


def test_timeline_parses_and_plays_segments_back_to_back(bfm, tmp_path):
    from motions.clip import from_qpos, save_clip

    qpos = np.tile(load_model().qpos0, (12, 1))
    qpos[:, 7 + 45] = np.linspace(0.0, 1.0, 12)  # a shoulder moving
    clip_path = save_clip(from_qpos(qpos, name="arm"), tmp_path / "arm.npz")
    tl = Timeline.from_string(bfm.prompt, f"move-ego-0-2:1,t_pose:0.5,{clip_path}:0.5", fps=30)
    assert [s.kind for s in tl.segments] == ["reward", "goal", "clip"]
    assert [s.steps for s in tl.segments] == [30, 15, 15]
    zs = tl.z_per_step()
    assert zs.shape == (60, bfm.z_dim) and len(list(tl)) == 60
    np.testing.assert_allclose(zs[:30], np.repeat(bfm.prompt.reward("move-ego-0-2")[None], 30, 0), rtol=1e-6)
    np.testing.assert_allclose(zs[30:45], np.repeat(bfm.prompt.goal("t_pose")[None], 15, 0), rtol=1e-6)
    track = bfm.prompt.track(clip_path)  # 11 per-step zs, then the last one is held
    np.testing.assert_allclose(zs[45:56], track, rtol=1e-6)
    np.testing.assert_allclose(zs[56:], np.repeat(track[-1:], 4, 0), rtol=1e-6)
    assert list(tl.segment_index()) == [0] * 30 + [1] * 15 + [2] * 15


@pytest.mark.parametrize("text, match", [
    ("", "empty entry"), ("jump-2:2,,t_pose:1", "empty entry"), ("jump-2", "ITEM:SECONDS"),
    ("jump-2:fast", "not a number"), ("jump-2:-1", "positive"), (":3", "ITEM:SECONDS"),
])
def test_timeline_syntax_errors(text, match):
    with pytest.raises(PromptError, match=match):
        parse_timeline(text)


def test_timeline_unknown_item_names_it(bfm):
    with pytest.raises(PromptError, match="'moonwalk' is not a clip file, a goal pose, a built-in clip"):
        Timeline.from_string(bfm.prompt, "jump-2:1,moonwalk:2")


def test_builtin_clip_names_work_as_motions(bfm):
    from motions.synthetic import default_clips

    walk = next(c for c in default_clips() if c.name == "walk")
    np.testing.assert_allclose(bfm.prompt.track("walk"), bfm.prompt.track(walk), rtol=1e-6)
    tl = Timeline.from_string(bfm.prompt, "walk:1,t_pose:1")
    assert [s.kind for s in tl.segments] == ["clip", "goal"]
    with pytest.raises(PromptError, match="nor a built-in clip"):
        bfm.prompt.imitate("moonwalk")


def test_prompts_steer_a_trained_toy_model(tmp_path):
    """Real behaviour: train FB-CPR on the 2-D point mass for 15k steps (~20 s), load it as a BFM, and check that
    goal, reward and tracking prompts beat random latents (the numbers at 40k steps are in docs/usage.md)."""
    from pathlib import Path

    from fbcpr.core.config import load_config
    from fbcpr.envs import toy as pm
    from fbcpr.train.trainer import Trainer

    cfg = load_config(Path(__file__).parents[1] / "fbcpr" / "configs" / "toy.yaml")
    cfg.train.total_env_steps = 15_000
    Trainer(cfg, tmp_path / "toy", progress=False).run()
    toy = BFM.load(tmp_path / "toy")
    rng = np.random.default_rng(0)

    def roll(z_at, n, reward=None, start=None, steps=100):
        env = pm.PointMassVectorEnv(n, reward=reward, max_episode_steps=steps + 1)
        obs, _ = env.reset(seed=1, options=None if start is None else {"qpos": start, "qvel": np.zeros_like(start)})
        traj, ret = [], np.zeros(n)
        for k in range(steps):
            obs, r, *_ = env.step(toy.act(obs, z_at(k)))
            traj.append(obs.copy())
            ret += r
        return np.stack(traj, 1), ret

    def random_z():
        return toy.project_z(rng.normal(size=toy.z_dim))

    prompt_dist, random_dist = [], []
    for g in pm.GOALS:
        z_goal, z_rand = toy.prompt.goal(g), random_z()
        prompt_dist.append(np.linalg.norm(roll(lambda k: z_goal, 8)[0][:, -1] - g, axis=1).mean())
        random_dist.append(np.linalg.norm(roll(lambda k: z_rand, 8)[0][:, -1] - g, axis=1).mean())
    assert np.mean(prompt_dist) < 0.7 * np.mean(random_dist)

    prompt_ret = random_ret = 0.0
    for task, fn in pm.TASKS.items():
        z_task, z_rand = toy.prompt.reward(lambda o, a, q, v: fn(o)), random_z()
        prompt_ret += roll(lambda k: z_task, 8, reward=task)[1].mean()
        random_ret += roll(lambda k: z_rand, 8, reward=task)[1].mean()
    assert prompt_ret > 2 * random_ret

    track_err, imitate_err = [], []
    for ref in pm.demo_paths().values():
        zs, z_one = toy.prompt.track(ref), toy.prompt.imitate(ref)
        start = ref[:1]
        tracked = roll(lambda k: zs[k], 1, start=start, steps=len(ref) - 1)[0][0]
        imitated = roll(lambda k: z_one, 1, start=start, steps=len(ref) - 1)[0][0]
        track_err.append(np.linalg.norm(tracked - ref[1:], axis=1).mean())
        imitate_err.append(np.linalg.norm(imitated - ref[1:], axis=1).mean())
    assert np.mean(track_err) < 0.7 * np.mean(imitate_err)


def test_unknown_names_suggest_the_closest_and_do_not_repeat_themselves():
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.prompt import goal_observation, reward_fn

    with pytest.raises(PromptError) as err:
        reward_fn("jupm-2")
    assert "did you mean 'jump-2'?" in str(err.value) and str(err.value).count("jupm-2") == 1
    with pytest.raises(PromptError, match=r"unknown goal 't-pose' \(did you mean 't_pose'\?\)"):
        goal_observation("t-pose", 358)


def test_a_folder_given_as_a_clip_lists_its_clips(tmp_path):
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.prompt import load_motion
    from motions.clip import save_clip
    from motions.synthetic import stand

    with pytest.raises(PromptError, match="is a directory, not a clip; it holds no clip"):
        load_motion(tmp_path)
    save_clip(stand(seconds=0.5), tmp_path / "stand.npz")
    with pytest.raises(PromptError, match=r"is a directory, not a clip; pick one of its 1 clips: stand.npz"):
        load_motion(tmp_path)
