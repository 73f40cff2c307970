"""benchmarks/bf16_agreement.py: the bf16 update's gradients against float32's, on the same weights and draws."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import torch
import yaml

from conftest import tiny_humanoid_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.agent import FBCPRAgent

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "bf16_agreement.py"
spec = importlib.util.spec_from_file_location("bf16_agreement", SCRIPT)
bf16_agreement = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bf16_agreement)


def tiny_agent() -> tuple[FBCPRAgent, dict, torch.Tensor]:
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 20, "action_dim": 6},
                            "agent": {"batch_size": 32, "seq_length": 4}})
    agent = FBCPRAgent(cfg.model, cfg.agent)
    g = torch.Generator().manual_seed(0)
    batch = {"obs": torch.randn(32, 20, generator=g), "action": torch.rand(32, 6, generator=g) * 2 - 1,
             "next_obs": torch.randn(32, 20, generator=g), "z": agent.model.sample_z(32),
             "terminated": torch.zeros(32)}
    return agent, batch, torch.randn(8, 4, 20, generator=g)


def test_gradients_take_no_step_and_repeat_exactly_so_only_the_precision_differs():
    agent, batch, windows = tiny_agent()
    weights = {k: v.clone() for k, v in agent.model.state_dict().items()}
    first, losses = bf16_agreement.gradients(agent, batch, windows, bf16=False)
    again, same = bf16_agreement.gradients(agent, batch, windows, bf16=False)
    assert all(torch.equal(v, agent.model.state_dict()[k]) for k, v in weights.items())  # no step, normaliser back
    assert losses == same and all(torch.equal(first[k], again[k]) for k in first)          # the same random draws
    assert set(first) == {"forward_map", "backward_map", "actor", "critic", "discriminator"}
    low, _ = bf16_agreement.gradients(agent, batch, windows, bf16=True)
    for name, (cos, rel) in bf16_agreement.compare(first, low).items():
        assert 0.9 < cos < 1.0 and 0.0 < rel < 0.5, (name, cos, rel)   # bf16 rounds, but keeps the direction


def test_command_line_prints_every_trained_network_and_loss(tmp_path, two_clips):
    tiny_humanoid_checkpoint(tmp_path, "base", seed=0)
    config = {"model": {"preset": "tiny"}, "agent": {"batch_size": 16, "seq_length": 4},
              "env": {"name": "humanoid", "motions": str(two_clips), "max_episode_steps": 20},
              "train": {"num_envs": 2, "rollout_steps": 8, "buffer_capacity": 200, "reward_buffer_size": 8}}
    (tmp_path / "run.yaml").write_text(yaml.safe_dump(config))
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "run.yaml"), "--init-from",
                          str(tmp_path / "base"), "--steps", "32", "--batches", "2"],
                         capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0].startswith("2 batches of 16 from 32 transitions")
    rows = {line.split()[0]: line.split() for line in out[2:]}
    for name in ("forward_map", "backward_map", "actor", "critic", "discriminator"):
        assert 0.5 < float(rows[name][1]) <= 1.0   # the cosine of the bf16 gradient with float32's
    assert float(rows["fb_loss"][1]) < 0.1       # relative difference of the loss


def test_a_config_of_another_method_is_refused_by_name(tmp_path):
    (tmp_path / "td3.yaml").write_text(yaml.safe_dump({"algorithm": "td3", "env": {"name": "toy"},
                                                       "agent": {"reward": {"task": "reach-top-right"}}}))
    run = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "td3.yaml")], capture_output=True, text=True)
    assert run.returncode != 0 and "td3.yaml: algorithm 'td3'" in run.stderr
