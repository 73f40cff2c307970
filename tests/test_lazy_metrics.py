"""Update metrics stay on the device until read, and keep the values of their own update."""
import math

import torch

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.nn.lazy_metrics import LazyMetrics
from fbcpr.methods.td3.agent import TD3Agent

torch.set_num_threads(1)


def fbcpr_agent():
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}, "agent": {"batch_size": 32}})
    return FBCPRAgent(cfg.model, cfg.agent, seed=0)


def batch_for(agent, seed):
    g = torch.Generator().manual_seed(seed)
    return ({"obs": torch.randn(32, 6, generator=g), "action": torch.rand(32, 3, generator=g) * 2 - 1,
             "next_obs": torch.randn(32, 6, generator=g), "z": agent.model.sample_z(32, g),
             "terminated": torch.zeros(32)}, torch.randn(4, 8, 6, generator=g))


def test_values_are_read_once_on_first_access():
    values = {"a": torch.tensor(1.5), "b": torch.tensor(-2.0, dtype=torch.float64)}
    m = LazyMetrics(values, {"c": 3.0})
    assert not m.read
    assert "a" in m and "c" in m and "z" not in m and len(m) == 3 and not m.read  # names alone copy nothing
    assert dict(m) == {"c": 3.0, "a": 1.5, "b": -2.0} and m.read
    assert all(type(v) is float for v in m.values())


def test_an_update_returns_unread_metrics_that_a_later_update_does_not_change():
    agent = fbcpr_agent()
    first = agent.update(*batch_for(agent, 0))
    assert isinstance(first, LazyMetrics) and not first.read
    twin = fbcpr_agent()
    expected = dict(twin.update(*batch_for(twin, 0)))
    agent.update(*batch_for(agent, 1))                 # a second update before the first one's metrics are read
    assert dict(first) == expected
    assert all(math.isfinite(v) for v in expected.values()) and "fb_loss" in expected


def test_td3_metrics_are_lazy():
    cfg = config_from_dict({"algorithm": "td3", "model": {"hidden_dim": 16, "hidden_layers": 1},
                            "agent": {"batch_size": 32, "reward": {"task": "reach-top-right"}}})
    cfg.model.obs_dim, cfg.model.action_dim = 2, 2
    agent = TD3Agent(cfg.model, cfg.agent, task_reward=lambda o, q, v: torch.ones(o.shape[0]))
    g = torch.Generator().manual_seed(0)
    batch = {k: torch.rand(32, 2, generator=g) for k in ("obs", "action", "next_obs", "qpos", "qvel")}
    batch["terminated"] = torch.zeros(32)
    m = agent.update(batch, torch.rand(4, 8, 2))
    assert isinstance(m, LazyMetrics) and not m.read
    assert m["reward"] == 1.0 and set(m) == {"critic_loss", "actor_loss", "reward", "q"}
