"""Continuing a model while holding what prompts it: a frozen B and normaliser (`agent.freeze_backward`) and the
actor anchored on demonstration pairs (`agent.anchor_actor`), kept across a resume and refused without --init-from."""
import copy
import shutil

import pytest
import torch

from fbcpr.checkpoint import CheckpointError
from fbcpr.config import ConfigError, config_from_dict
from fbcpr.fb_cpr.agent import FBCPRAgent
from fbcpr.fb_cpr.anchor import ActorAnchor
from fbcpr.fb_cpr.imitation import encode_windows
from fbcpr.trainer import Trainer

torch.set_num_threads(1)


def make_agent(**agent):
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3},
                            "agent": {"batch_size": 32, **agent}})
    return FBCPRAgent(cfg.model, cfg.agent, seed=0)


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


def toy_cfg(**agent):
    return config_from_dict({
        "model": {"preset": "tiny"},
        "agent": {"batch_size": 32, **agent},
        "env": {"name": "toy", "max_episode_steps": 30},
        "train": {"total_env_steps": 100_000, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                  "updates_per_rollout": 2, "buffer_capacity": 1000, "priority_every": 0, "eval_every": 0,
                  "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 0, "save_buffer": True,
                  "torch_threads": 1},
    })


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
