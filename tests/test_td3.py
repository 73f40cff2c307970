"""TD3 single-task agent: config, reward sources, exact resume, checkpoints, and learning one toy task."""
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.core.checkpoint import CheckpointError, load_checkpoint
from fbcpr.core.config import config_from_dict, load_config
from fbcpr.core.errors import ConfigError
from fbcpr.methods.td3.agent import TD3Agent
from fbcpr.methods.td3.model import TD3Model
from fbcpr.eval.toy import task_return
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)
CONFIGS = Path(__file__).resolve().parents[1] / "fbcpr" / "configs"


def tiny_cfg(reward=None, **train):
    return config_from_dict({
        "algorithm": "td3",
        "model": {"hidden_dim": 16, "hidden_layers": 1},
        "agent": {"batch_size": 32, "reward": reward or {"task": "reach-top-right"}},
        "env": {"name": "toy", "max_episode_steps": 30},
        "train": {"total_env_steps": 100_000, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                  "updates_per_rollout": 2, "buffer_capacity": 1000, "priority_every": 0, "eval_every": 0,
                  "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 0, "save_buffer": True,
                  "torch_threads": 1, **train},
    })


def state_of(tr):
    sd = {f"m.{k}": v.clone() for k, v in tr.agent.model.state_dict().items()}
    sd.update({f"t.{k}": v.clone() for k, v in tr.agent.target_critic.state_dict().items()})
    sd.update({f"s.{k}": v.clone() for k, v in tr.agent.state()[0].items()})
    return sd


def test_reward_sources_are_validated_and_named(tmp_path):
    with pytest.raises(ConfigError, match="^agent.reward: give a task, an imitation reward, or both"):
        config_from_dict({"algorithm": "td3", "agent": {"reward": {"task_weight": 1.0}}})
    with pytest.raises(ConfigError, match="^agent.lr_f: unknown key"):     # FB-CPR's keys are not TD3's
        config_from_dict({"algorithm": "td3", "agent": {"lr_f": 1e-4, "reward": {"task": "x"}}})
    with pytest.raises(ConfigError, match="^agent.reward.task: unknown toy task 'nope'"):
        Trainer(tiny_cfg({"task": "nope"}), tmp_path)
    with pytest.raises(ConfigError, match="^agent.reward.imitation: unknown imitation reward 'gail'"):
        Trainer(tiny_cfg({"imitation": "gail"}), tmp_path)


class ConstantImitation:
    """An imitation reward of 2 everywhere (records what it was fitted on)."""

    def __init__(self):
        self.fitted = 0

    def fit(self, expert_windows, batch):
        self.fitted += 1
        return {"imitation_loss": 0.5}

    def reward(self, obs, next_obs, z=None):
        return torch.full((obs.shape[0],), 2.0)


def test_reward_is_the_weighted_sum_of_task_and_imitation():
    cfg = tiny_cfg({"task": "reach-top-right", "task_weight": 0.25, "imitation": "amp", "imitation_weight": 0.5})
    cfg.model.obs_dim, cfg.model.action_dim = 2, 2
    imitation = ConstantImitation()
    agent = TD3Agent(cfg.model, cfg.agent, task_reward=lambda o, q, v: o[:, 0] ** 2, imitation=imitation)
    g = torch.Generator().manual_seed(0)
    batch = {k: torch.rand(32, 2, generator=g) for k in ("obs", "action", "next_obs", "qpos", "qvel")}
    batch["terminated"] = torch.zeros(32)
    torch.testing.assert_close(agent.reward(batch), 0.25 * batch["next_obs"][:, 0] ** 2 + 0.5 * 2.0)
    before = {k: v.clone() for k, v in agent.model.state_dict().items()}
    target_before = {k: v.clone() for k, v in agent.target_critic.state_dict().items()}
    metrics = agent.update(batch, torch.rand(4, 8, 2))
    assert imitation.fitted == 1 and metrics["imitation_loss"] == 0.5
    after = agent.model.state_dict()
    for net in ("actor", "critic"):
        assert any(not torch.equal(before[k], after[k]) for k in after if k.startswith(net)), net
    for k, v in agent.target_critic.state_dict().items():   # Polyak with tau
        torch.testing.assert_close(v, (1 - cfg.agent.tau) * target_before[k] + cfg.agent.tau * after[f"critic.{k}"])


def test_resume_is_exact_and_checkpoints_hold_a_td3_model(tmp_path):
    a = Trainer(tiny_cfg(), tmp_path / "a", progress=False)
    a.run(max_env_steps=120)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    a.run(max_env_steps=80)
    b = Trainer(tiny_cfg(), tmp_path / "b", resume=True, progress=False)
    b.run(max_env_steps=80)
    sa, sb = state_of(a), state_of(b)
    assert sa.keys() == sb.keys() and not [k for k in sa if not torch.equal(sa[k], sb[k])]
    ck = load_checkpoint(tmp_path / "a" / "checkpoints" / (tmp_path / "a" / "checkpoints" / "latest").read_text())
    assert ck.algorithm == "td3" and isinstance(ck.model, TD3Model)
    obs = np.random.default_rng(0).uniform(-1, 1, (5, 2)).astype(np.float32)
    np.testing.assert_array_equal(ck.model.act(obs), a.agent.model.act(obs))
    with pytest.raises(CheckpointError, match="holds a td3 agent, not a prompt-able FB-CPR model"):
        BFM.load(tmp_path / "a")
    with pytest.raises(ConfigError, match="algorithm: 'fb_cpr' differs from 'td3'"):
        Trainer(config_from_dict({"env": {"name": "toy"}, "model": {"preset": "tiny"}}), tmp_path / "c",
                init_from=tmp_path / "a")


def test_td3_learns_its_toy_task_far_above_random(tmp_path):
    cfg = load_config(CONFIGS / "td3-toy.yaml")
    cfg.train.total_env_steps = 6000
    tr = Trainer(cfg, tmp_path, progress=False)
    tr.run()
    task = cfg.agent.reward.task
    learned = task_return(tr.agent.model.eval(), task, np.random.default_rng(1), prompt=False)
    random = task_return(None, task, np.random.default_rng(1), prompt=False)
    assert learned > 50 and learned > 5 * random, (learned, random)
