"""lab/experiments/prompt_share_train.py: the share of z draws that are named reward prompts, the prompts inferred at
the warm start as the anchor infers them, and the refusals (an unfrozen B, no reward sample, a resume)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import prompt_share_train
import pytest
import torch

from fbcpr.core import registry
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.methods.fb_cpr.anchor import reward_prompts
from fbcpr.nn.networks import project_sphere

SCRIPT = Path(__file__).parents[1] / "experiments" / "prompt_share_train.py"


def near(x: float):
    return lambda next_obs, qpos, qvel: np.exp(-np.abs(next_obs[:, 0] - x))


def make_agent(share: float, tasks: tuple[str, ...] = ("1", "-2"), **agent):
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3},
                            "agent": {"batch_size": 32, "freeze_backward": True, **agent}})
    rewards = {t: near(float(t)) for t in tasks}
    prompt_share_train.PromptShareAgent.tasks, prompt_share_train.PromptShareAgent.share = tasks, share
    return prompt_share_train.PromptShareAgent(cfg.model, cfg.agent, seed=0, prompt_rewards=rewards)


def sample() -> dict[str, np.ndarray]:
    g = np.random.default_rng(0)
    return {"next_obs": g.normal(size=(200, 6)).astype(np.float32), "qpos": np.zeros((200, 1)),
            "qvel": np.zeros((200, 1))}


def test_a_share_of_draws_are_the_warm_started_prompts() -> None:
    agent = make_agent(0.3)
    before = agent.sample_z(64, None, None)  # before the warm start: nu alone, no prompt
    agent.warm_started(sample)
    expected = reward_prompts(agent.model, sample(), agent.prompt_rewards)
    assert agent.prompt_z is not None and torch.allclose(agent.prompt_z, expected)
    z = agent.sample_z(4000, None, project_sphere(torch.randn(5, agent.z_dim)))
    is_prompt = (z[:, None, :] == agent.prompt_z[None]).all(-1)  # (n, tasks)
    share = is_prompt.any(-1).float().mean().item()
    assert 0.26 < share < 0.34, share
    per_task = is_prompt.float().mean(0)
    assert torch.all(per_task > 0.12), per_task  # both prompts drawn
    assert not (before[:, None, :] == agent.prompt_z[None]).all(-1).any()
    norms = torch.linalg.vector_norm(z, dim=-1)
    assert torch.allclose(norms, torch.full_like(norms, agent.z_dim ** 0.5), rtol=1e-4)


def test_relabelled_batch_rows_take_the_prompts_too() -> None:
    agent = make_agent(1.0, tasks=("1",), relabel_prob=1.0)
    agent.warm_started(sample)
    z = agent.relabel(torch.zeros(50, agent.z_dim), torch.randn(50, agent.z_dim), None)
    assert torch.equal(z, agent.prompt_z.expand(50, -1))


def test_refusals() -> None:
    with pytest.raises(ConfigError, match="freeze_backward"):
        make_agent(0.2, freeze_backward=False)
    agent = make_agent(0.2)
    with pytest.raises(ConfigError, match="reward-inference sample"):
        agent.warm_started(lambda: None)
    run = subprocess.run([sys.executable, str(SCRIPT), "--tasks", "move-ego-0-0", "cfg.yaml", "--resume"],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "--resume" in run.stderr


def test_install_points_the_registry_at_the_subclass(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.METHODS, "fb_cpr", registry.METHODS["fb_cpr"])
    prompt_share_train.install(["move-ego-0-0"], 0.25)
    assert registry.METHODS["fb_cpr"].agent_class() is prompt_share_train.PromptShareAgent
    assert prompt_share_train.PromptShareAgent.share == 0.25
    with pytest.raises(SystemExit):
        prompt_share_train.install(["move-ego-0-0"], 0.0)
