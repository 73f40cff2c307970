"""Continuing a model while holding what prompts it: a frozen B and normaliser (`agent.freeze_backward`), the
actor anchored on demonstration pairs (`agent.anchor_actor`) and on held reward prompts (`agent.anchor_rewards`),
the loaded reward sample kept (`train.keep_reward_sample`); kept across a resume and refused without --init-from."""
import copy
import shutil

import numpy as np
import pytest
import torch

from conftest import toy_run_config
from fbcpr.core.checkpoint import CheckpointError
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.methods.fb_cpr.anchor import ActorAnchor
from fbcpr.methods.fb_cpr.imitation import encode_windows
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)


def far_from(x: float):
    """A made-up task reward on (next_obs, qpos, qvel): higher the closer the first coordinate is to x."""
    return lambda next_obs, qpos, qvel: np.exp(-np.abs(next_obs[:, 0] - x))


def make_agent(free=None, **agent):
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3},
                            "agent": {"batch_size": 32, **agent}})
    return FBCPRAgent(cfg.model, cfg.agent, seed=0, task_reward=lambda name: far_from(float(name)), free=free)


def batches(agent, k):
    out = []
    for seed in range(k):
        g = torch.Generator().manual_seed(seed)
        batch = {"obs": torch.randn(32, 6, generator=g) * 2 + 1, "action": torch.rand(32, 3, generator=g) * 2 - 1,
                 "next_obs": torch.randn(32, 6, generator=g) * 2 + 1, "z": agent.model.sample_z(32, g),
                 "terminated": torch.zeros(32)}
        out.append((batch, torch.randn(4, 8, 6, generator=g) + 1.0))
    return out


def test_frozen_backward_keeps_b_and_its_statistics_while_the_rest_learns():
    for frozen in (True, False):
        agent = make_agent(freeze_backward=frozen)
        agent.update(*batches(agent, 1)[0])          # statistics from a first batch, as a loaded model has them
        before = copy.deepcopy(agent.model.state_dict())
        for batch, windows in batches(agent, 3):
            agent.update(batch, windows)
        after = agent.model.state_dict()
        moved = {k.split(".")[0] for k in after if not torch.equal(before[k], after[k])}
        assert {"forward_map", "actor", "critic"} <= moved
        assert ("backward_map" in moved, "obs_normalizer" in moved) == (not frozen, not frozen), moved
        assert ("backward_map" in agent.optimizers) is not frozen


def test_actor_anchor_holds_the_mean_on_demonstration_pairs_and_nothing_else():
    data = None
    gaps = {}
    for coef in (0.0, 30.0):
        agent = make_agent(anchor_actor=coef, lr_actor=3e-3)
        agent.warm_started()
        start = ActorAnchor(agent.model)
        data = data or batches(agent, 40)
        for batch, windows in data:
            metrics = agent.update(batch, windows)
        assert ("anchor_gap" in metrics) is (coef > 0)
        windows = data[0][1]
        m = agent.model
        with torch.no_grad():
            z = encode_windows(m, m.normalize(windows)).repeat_interleave(8, 0)
            flat = windows.reshape(-1, 6)
            gaps[coef] = float(start.gap(m, flat, m.normalize(flat), z))
            free = float(start.gap(m, flat, m.normalize(flat), m.sample_z(32, torch.Generator().manual_seed(9))))
        if coef > 0:  # the actor still learns away from the demonstration pairs
            assert free > 2 * gaps[coef], (free, gaps[coef])
    assert 0 < gaps[30.0] < 0.3 * gaps[0.0], gaps


def test_anchor_free_clips_leave_their_windows_to_learn_while_the_others_stay_held():
    free = np.array([False, True])          # clip 0 is held, clip 1 (a new skill's) is left free
    gaps = {}
    for coef in (0.0, 30.0):
        agent = make_agent(free if coef else None, anchor_actor=coef, lr_actor=3e-3,
                           **({"anchor_free": ["new-*"]} if coef else {}))
        agent.warm_started()
        start = ActorAnchor(agent.model)
        data = batches(agent, 40)
        for i, (batch, windows) in enumerate(data):
            windows[2:] -= 3.0                    # windows 2 and 3 come from the free clip, far from the held ones
            batch["window_clip"] = torch.tensor([0, 0, 1, 1])
            agent.update(batch, windows)
        m = agent.model
        with torch.no_grad():
            windows = data[0][1]
            for name, part in (("held", windows[:2]), ("free", windows[2:])):
                flat = part.reshape(-1, 6)
                z = encode_windows(m, m.normalize(part)).repeat_interleave(8, 0)
                gaps[coef, name] = float(start.gap(m, flat, m.normalize(flat), z))
    assert gaps[30.0, "held"] < 0.3 * gaps[0.0, "held"], gaps        # held as the plain anchor holds
    assert gaps[30.0, "free"] > 0.5 * gaps[0.0, "free"], gaps        # and the free windows move as if unanchored
    assert gaps[30.0, "free"] > 3 * gaps[30.0, "held"], gaps
    with pytest.raises(ValueError, match="anchor_free needs each window's clip"):
        agent.update(*batches(agent, 1)[0])


def test_anchor_free_names_clips_of_the_library_and_the_trainer_marks_each_window(tmp_path):
    with pytest.raises(ConfigError, match="anchor_free: .*needs agent.anchor_actor > 0"):
        toy_cfg(anchor_free=["circle-*"])
    held = {"freeze_backward": True, "anchor_actor": 1.0}
    Trainer(toy_cfg(), tmp_path / "base", progress=False).save()
    for patterns, match in ((["circle-*", "jump*"], "'jump\\*' matches no clip of env.motions"),
                            (["*"], ".* match all 5 clips, so the anchor would hold nothing")):
        with pytest.raises(ConfigError, match=f"agent.anchor_free: {match}"):
            Trainer(toy_cfg(anchor_free=patterns, **held), tmp_path / "x", progress=False,
                    init_from=tmp_path / "base")
    run = Trainer(toy_cfg(anchor_free=["circle-*"], **held), tmp_path / "held", progress=False,
                  init_from=tmp_path / "base")
    library = run.bundle.library
    np.testing.assert_array_equal(run.agent.free.numpy(), [n.startswith("circle-") for n in library.names])
    notice = (tmp_path / "held" / "warnings.txt").read_text()
    assert "anchor leaves 2 of 5 clips free: circle-ccw, circle-cw-small" in notice
    run.run(max_env_steps=100)
    batch, windows = run.learner.sample_batch()
    clip = batch["window_clip"].numpy()
    for window, m in zip(windows.numpy(), clip):       # each window lies inside the clip it is marked with
        frames = library.frames[library.offsets[m]:library.offsets[m] + library.lengths[m]]
        assert np.any(np.all(np.isclose(frames, window[0]), axis=1))
    assert "anchor_gap" in run.agent.update(batch, windows)
    plain = Trainer(toy_cfg(**held), tmp_path / "plain", progress=False, init_from=tmp_path / "base")
    plain.run(max_env_steps=100)
    assert "window_clip" not in plain.learner.sample_batch()[0]


def toy_cfg(train=None, **agent):
    return toy_run_config(agent=agent, train={"save_buffer": True, **(train or {})})


def test_a_held_run_continues_from_its_model_keeps_the_anchor_on_resume_and_needs_init_from(tmp_path):
    held = {"freeze_backward": True, "anchor_actor": 1.0}
    for key in held:
        with pytest.raises(ConfigError, match=f"agent.{key}: .*needs --init-from"):
            Trainer(toy_cfg(**{key: held[key]}), tmp_path / "fresh", progress=False)
    base = Trainer(toy_cfg(), tmp_path / "base", progress=False)
    base.run(max_env_steps=80)
    loaded = copy.deepcopy(base.agent.model.state_dict())
    run = Trainer(toy_cfg(**held), tmp_path / "held", progress=False, init_from=tmp_path / "base")
    run.run(max_env_steps=120)
    now = run.agent.model.state_dict()
    for k in now:
        if k.startswith(("backward_map.", "obs_normalizer.")):
            assert torch.equal(now[k], loaded[k]), k
    assert any(not torch.equal(now[k], loaded[k]) for k in now if k.startswith("actor."))
    anchor = run.agent.anchor.state_dict()
    for k, v in anchor.items():
        assert torch.equal(v, loaded[k]), k          # the anchor is the loaded actor and its statistics
    shutil.copytree(tmp_path / "held", tmp_path / "again")
    again = Trainer(toy_cfg(**held), tmp_path / "again", resume=True, progress=False)
    assert all(torch.equal(v, again.agent.anchor.state_dict()[k]) for k, v in anchor.items())
    with pytest.raises(CheckpointError, match="actor anchor"):   # a run saved without an anchor cannot give one
        Trainer(toy_cfg(anchor_actor=1.0), tmp_path / "base", resume=True, progress=False)


def test_reward_anchor_holds_the_actor_under_held_reward_prompts_on_the_batch_states():
    data = None
    gaps = {}
    g = torch.Generator().manual_seed(5)
    sample = {"next_obs": (torch.randn(200, 6, generator=g) * 2 + 1).numpy(), "qpos": np.zeros((200, 1)),
              "qvel": np.zeros((200, 1))}
    for held in ([], ["-1", "2"]):
        agent = make_agent(anchor_actor=30.0, freeze_backward=True, anchor_rewards=held, lr_actor=3e-3)
        data = data or batches(agent, 41)
        agent.update(*data[0])                        # statistics from a first batch, as a loaded model has them
        agent.warm_started(lambda: sample)
        start = ActorAnchor(agent.model)
        m = agent.model
        prompts = torch.stack([torch.as_tensor(m.project_z(torch.as_tensor(
            np.exp(10 * (r - r.max())) * r, dtype=torch.float32) @ m.backward(torch.as_tensor(sample["next_obs"]))))
            for r in (far_from(-1.0)(sample["next_obs"], None, None), far_from(2.0)(sample["next_obs"], None, None))])
        if held:  # the held z's are the weighted-regression prompts of the loaded B over the loaded sample
            assert torch.allclose(agent.anchor.prompts, prompts, atol=1e-4)
        for batch, windows in data[1:]:
            metrics = agent.update(batch, windows)
        assert ("anchor_gap_rewards" in metrics) is bool(held)
        obs = torch.cat([b["obs"] for b, _ in data[:4]])
        with torch.no_grad():
            z = prompts.repeat(len(obs) // 2, 1)
            gaps[bool(held)] = float(start.gap(m, obs, m.normalize(obs), z))
    assert 0 < gaps[True] < 0.3 * gaps[False], gaps


def test_held_reward_prompts_are_the_reward_prompts_of_the_loaded_checkpoint(tmp_path):
    from fbcpr import BFM
    from fbcpr.core.checkpoint import load_checkpoint
    from humanoid_env.tasks import get_reward
    from conftest import tiny_humanoid_checkpoint

    path = tiny_humanoid_checkpoint(tmp_path, "loaded", seed=3)
    ckpt = load_checkpoint(path)
    names = ["move-ego-0-0", "raisearms-l-l"]
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8, "freeze_backward": True, "anchor_actor": 1.0,
                                      "anchor_rewards": names}})
    agent = FBCPRAgent(cfg.model, cfg.agent, task_reward=lambda n: (lambda o, q, v, f=get_reward(n): f(o, None, q, v)))
    agent.model.load_state_dict(ckpt.model.state_dict())
    agent.warm_started(ckpt.reward_buffer)
    bfm = BFM.load(path)
    for name, held in zip(names, agent.anchor.prompts):
        np.testing.assert_allclose(held.numpy(), bfm.prompt.reward(name), atol=1e-4)
    with pytest.raises(ConfigError, match="no reward-inference sample"):
        agent.warm_started(lambda: None)


def test_a_warm_start_holds_the_loaded_models_stored_prompt_where_it_has_one(tmp_path):
    """The shipped model's stored prompts are refined at export, so they are not what its B infers: the anchor must
    hold the z the user's prompt plays, or a held family is lost under its own prompt."""
    from fbcpr import BFM
    from fbcpr.inference.reward_prompts import RewardPrompts, weights_digest
    from conftest import tiny_humanoid_checkpoint

    original = tiny_humanoid_checkpoint(tmp_path, "loaded", seed=3)
    bfm = BFM.load(original)
    stored = bfm.project_z(np.random.default_rng(0).normal(size=bfm.z_dim))  # far from what B infers
    bfm.reward_prompts = RewardPrompts({"move-ego-0-0": stored}, 32, weights_digest(bfm.model))
    path = bfm.save(tmp_path / "with-prompts")
    names = ["move-ego-0-0", "raisearms-l-l"]
    cfg = config_from_dict({"model": {"preset": "tiny"},
                            "agent": {"seq_length": 4, "batch_size": 8, "freeze_backward": True, "anchor_actor": 1.0,
                                      "anchor_rewards": names},
                            "env": {"name": "humanoid", "max_episode_steps": 30},
                            "train": {"num_envs": 2, "buffer_capacity": 1000, "priority_every": 0,
                                      "reward_buffer_size": 0, "warmup_steps": 20}})
    tr = Trainer(cfg, tmp_path / "run", init_from=path, progress=False)
    held = tr.agent.anchor.prompts.numpy()
    np.testing.assert_allclose(held[0], stored, atol=1e-5)                             # the stored prompt
    np.testing.assert_allclose(held[1], BFM.load(path).prompt.reward(names[1]), atol=1e-4)   # inferred: none stored
    inferred = BFM.load(original).prompt.reward(names[0])                   # what the B of the weights infers
    assert not np.allclose(held[0], inferred, atol=1e-2)
    assert any("1 of 2 held at the loaded model's stored prompts (move-ego-0-0)" in n for n in tr.agent.notices)


def test_held_reward_options_refuse_what_they_cannot_hold(tmp_path):
    for agent, match in (({"anchor_rewards": ["ring"], "anchor_actor": 1.0}, "anchor_rewards: .*freeze_backward"),
                         ({"anchor_rewards": ["ring"], "freeze_backward": True}, "anchor_rewards: .*anchor_actor"),
                         ({"anchor_rewards": ["ring", "ring"], "freeze_backward": True, "anchor_actor": 1.0},
                          "given twice")):
        with pytest.raises(ConfigError, match=match):
            toy_cfg(**agent)
    held = {"freeze_backward": True, "anchor_actor": 1.0}
    with pytest.raises(ConfigError, match="unknown toy task 'nowhere'"):
        Trainer(toy_cfg(anchor_rewards=["nowhere"], **held), tmp_path / "x", progress=False)
    with pytest.raises(ConfigError, match="train.keep_reward_sample: .*needs --init-from"):
        Trainer(toy_cfg(train={"keep_reward_sample": True}), tmp_path / "fresh", progress=False)
    Trainer(toy_cfg(), tmp_path / "bare", progress=False).save()      # reward_buffer_size 0: no sample saved
    with pytest.raises(ConfigError, match="keep_reward_sample: the --init-from checkpoint .* no reward"):
        Trainer(toy_cfg(train={"keep_reward_sample": True}), tmp_path / "k", progress=False, init_from=tmp_path / "bare")
    with pytest.raises(ConfigError, match="anchor_rewards: the --init-from checkpoint has no reward"):
        Trainer(toy_cfg(anchor_rewards=["ring"], **held), tmp_path / "r", progress=False, init_from=tmp_path / "bare")


def test_a_run_holding_reward_prompts_keeps_the_loaded_sample_and_prompts_across_a_resume(tmp_path):
    from fbcpr.core.checkpoint import latest_checkpoint, load_checkpoint

    sampled = {"reward_buffer_size": 60}
    base = Trainer(toy_cfg(train=sampled), tmp_path / "base", progress=False)
    base.run(max_env_steps=80)
    base.save()
    loaded = load_checkpoint(latest_checkpoint(tmp_path / "base" / "checkpoints")).reward_buffer()
    held = {"freeze_backward": True, "anchor_actor": 1.0, "anchor_rewards": ["ring", "reach-top-right"],
            "train": {**sampled, "keep_reward_sample": True}}
    run = Trainer(toy_cfg(**held), tmp_path / "held", progress=False, init_from=tmp_path / "base")
    prompts = run.agent.anchor.prompts.clone()
    assert prompts.shape == (2, run.agent.z_dim) and not torch.allclose(prompts[0], prompts[1])
    run.run(max_env_steps=120)
    run.save()

    def saved(root):
        return load_checkpoint(latest_checkpoint(root / "checkpoints")).reward_buffer()

    for key in loaded:       # the held run's checkpoints carry the loaded sample as it is, not its own transitions
        np.testing.assert_array_equal(saved(tmp_path / "held")[key], loaded[key])
    shutil.copytree(tmp_path / "held", tmp_path / "again")
    again = Trainer(toy_cfg(**held), tmp_path / "again", resume=True, progress=False)
    assert torch.equal(again.agent.anchor.prompts, prompts)
    again.run(max_env_steps=80)
    again.save()
    for key in loaded:
        np.testing.assert_array_equal(saved(tmp_path / "again")[key], loaded[key])
    unheld = {k: v for k, v in held.items() if k != "anchor_rewards"}
    shutil.copytree(tmp_path / "base", tmp_path / "base2")
    with pytest.raises(CheckpointError, match="actor anchor"):   # saved without held prompts: none to resume with
        Trainer(toy_cfg(**held), tmp_path / "base2", resume=True, progress=False)
    free = Trainer(toy_cfg(**{**unheld, "train": sampled}), tmp_path / "free", progress=False,
                   init_from=tmp_path / "base")
    free.run(max_env_steps=120)
    free.save()
    assert not np.array_equal(saved(tmp_path / "free")["next_obs"], loaded["next_obs"])
