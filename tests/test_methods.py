"""Method plug-ins: the registry behind `algorithm:`, the agent protocol, and checkpoints that record the method."""
import hashlib
import json

import pytest
import torch
import yaml

from fbcpr.core.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.core.registry import DEFAULT_ALGORITHM, METHODS, get_method
from fbcpr.core.protocols import OnlineAgent

torch.set_num_threads(1)


def fb_cfg(**extra):
    return config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}, **extra})


def rewrite(ckpt_dir, edit_config, edit_manifest=lambda m: None):
    """Edit config.yaml / manifest.json of a checkpoint and keep the manifest's checksums valid."""
    cfg = yaml.safe_load((ckpt_dir / "config.yaml").read_text())
    edit_config(cfg)
    (ckpt_dir / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    manifest = json.loads((ckpt_dir / "manifest.json").read_text())
    data = (ckpt_dir / "config.yaml").read_bytes()
    manifest["files"]["config.yaml"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    edit_manifest(manifest)
    (ckpt_dir / "manifest.json").write_text(json.dumps(manifest))


def test_algorithm_defaults_to_fb_cpr_and_unknown_names_are_config_errors():
    assert fb_cfg().algorithm == DEFAULT_ALGORITHM == "fb_cpr"
    with pytest.raises(ConfigError, match="^algorithm: unknown method 'sac'"):
        fb_cfg(algorithm="sac")
    with pytest.raises(ConfigError, match="^algorithm: expected str"):
        fb_cfg(algorithm=3)
    # the agent section is validated against the named method's schema
    with pytest.raises(ConfigError, match="^agent.nope: unknown key"):
        fb_cfg(agent={"nope": 1})


def test_fb_cpr_agent_satisfies_the_trainer_protocol():
    cfg = fb_cfg(agent={"batch_size": 32})
    agent = get_method("fb_cpr").agent(cfg, None, torch.device("cpu"), 0)
    assert isinstance(agent, FBCPRAgent) and isinstance(agent, OnlineAgent)
    z = agent.rollout_z(5, torch.randn(5, 6), torch.randn(5, 8, 6))
    assert z.shape == (5, agent.z_dim)
    torch.testing.assert_close(z.norm(dim=-1), torch.full((5,), agent.z_dim ** 0.5))
    a = agent.act(torch.randn(5, 6), z)
    assert a.shape == (5, 3) and a.abs().max() <= 1


def test_checkpoint_records_the_method_and_old_ones_load_as_fb_cpr(tmp_path):
    cfg = fb_cfg()
    save_checkpoint(tmp_path / "c", FBCPRModel(cfg.model), cfg)
    assert json.loads((tmp_path / "c" / "manifest.json").read_text())["algorithm"] == "fb_cpr"
    assert yaml.safe_load((tmp_path / "c" / "config.yaml").read_text())["algorithm"] == "fb_cpr"

    def drop(d):
        d.pop("algorithm")
    rewrite(tmp_path / "c", drop, drop)                       # as written before methods existed
    ck = load_checkpoint(tmp_path / "c")
    assert ck.algorithm == "fb_cpr" and isinstance(ck.model, FBCPRModel)

    rewrite(tmp_path / "c", lambda c: c.update(algorithm="fb_cpr"), lambda m: m.update(algorithm="td3"))
    with pytest.raises(CheckpointError, match="algorithm 'td3' disagrees"):
        load_checkpoint(tmp_path / "c")
    rewrite(tmp_path / "c", lambda c: c.update(algorithm="nope"), lambda m: m.pop("algorithm"))
    with pytest.raises(CheckpointError, match="config.yaml: invalid config.*unknown method 'nope'"):
        load_checkpoint(tmp_path / "c")


def test_every_registered_method_resolves():
    for method in METHODS.values():
        assert method.agent_config().__dataclass_fields__["batch_size"]
        assert hasattr(method.model(fb_cfg().model), "act")


def test_fb_cpr_discriminator_is_an_imitation_reward():
    from fbcpr.methods.fb_cpr.imitation import DiscriminatorReward
    from fbcpr.core.protocols import ImitationReward

    cfg = fb_cfg(agent={"batch_size": 32, "relabel_prob": 0.0})           # the agent scores the batch z as given
    agent = FBCPRAgent(cfg.model, cfg.agent, seed=0)
    g = torch.Generator().manual_seed(0)
    obs, next_obs, z = torch.randn(32, 6, generator=g), torch.randn(32, 6, generator=g), agent.model.sample_z(32, g)
    windows = torch.randn(4, 8, 6, generator=g) + 2.0                       # demonstrations live elsewhere
    agent.model.obs_normalizer.update(torch.cat([obs, windows.reshape(-1, 6)]))
    imitation = DiscriminatorReward(agent.model, lr=1e-3, grad_penalty=1.0)
    assert isinstance(imitation, ImitationReward)
    out = agent._losses(obs, torch.zeros(32, 3), next_obs, z, torch.zeros(32), windows)
    torch.testing.assert_close(imitation.reward(obs, next_obs, z).mean(), out["reward"])  # the agent's reward
    batch = {"obs": obs, "z": z}
    first = imitation.fit(windows, batch)
    for _ in range(30):
        last = imitation.fit(windows, batch)
    assert last["disc_expert"] - last["disc_online"] > first["disc_expert"] - first["disc_online"] + 0.2
    with pytest.raises(ValueError, match="needs the latent z"):
        imitation.reward(obs, next_obs)


def test_an_imitation_reward_brings_its_own_config_section(monkeypatch):
    """A new imitation reward is one registry line: the TD3 section then reads `agent.<name>` with its config."""
    from fbcpr.core import registry
    from fbcpr.core.errors import ConfigError
    from fbcpr.core.schema import _build
    from fbcpr.methods.td3.config import TD3Config

    monkeypatch.setitem(registry.IMITATION_REWARDS, "mine", registry.Reward(
        "fbcpr.rewards.progress:ProgressReward", "fbcpr.rewards.progress:ProgressConfig"))
    section = registry.with_imitation_sections(TD3Config, "Mine", "")
    cfg = _build(section, {"mine": {"scale": 2.5}, "reward": {"imitation": "mine"}}, "agent")
    assert cfg.mine.scale == 2.5 and cfg.amp.lr > 0 and cfg.reward.imitation == "mine"
    with pytest.raises(ConfigError, match="agent.mine.scale"):
        _build(section, {"mine": {"scale": -1.0}, "reward": {"imitation": "mine"}}, "agent")
