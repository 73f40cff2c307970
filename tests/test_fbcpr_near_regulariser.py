"""`agent.regulariser: near`: FB-CPR's critic on a z-conditioned NEAR energy (fbcpr/rewards/near/conditional.py)."""
import shutil

import pytest
import torch

from conftest import toy_run_config
from fbcpr.core.checkpoint import CheckpointError
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.rewards.near.conditional import ConditionalEnergy
from fbcpr.rewards.near.config import NEARConfig
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)


def toy_cfg(regulariser="near"):
    near = {"hidden_dim": 32, "hidden_layers": 2, "sigma_max": 1.0, "lr": 1e-3, "ema": 0.9, "num_levels": 5,
            "anneal_threshold": 0.01}
    return toy_run_config(agent={"regulariser": regulariser, "near": near},
                          train={"z_update_every": 7, "reward_buffer_size": 50, "save_buffer": True})


def learner_state(tr):
    """Model, targets, NEAR energy / EMA / step statistics and optimiser moments of a trainer's agent."""
    tensors, meta = tr.agent.state()
    sd = {f"m.{k}": v for k, v in tr.agent.model.state_dict().items()}
    sd.update({k: v for k, v in tensors.items() if not k.endswith("generator")})
    return sd, meta["near"]


def test_trains_on_the_toy_and_resumes_bit_for_bit(tmp_path):
    a = Trainer(toy_cfg(), tmp_path / "a", progress=False)
    disc_before = {k: v.clone() for k, v in a.agent.model.discriminator.state_dict().items()}
    a.run(max_env_steps=120)                        # warm-up, 8 updates over 4 rollout phases, a checkpoint
    metrics = a.learner.last_metrics
    for k in ("fb_loss", "critic_loss", "actor_loss", "dsm_loss", "reward", "near/gap"):
        assert torch.isfinite(torch.tensor(metrics[k])), k
    assert "disc_loss" not in metrics and set(a.agent.optimizers) == {"forward_map", "backward_map", "actor",
                                                                       "critic", "energy"}
    assert all(torch.equal(v, disc_before[k]) for k, v in a.agent.model.discriminator.state_dict().items())
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    a.run(max_env_steps=80)
    b = Trainer(toy_cfg(), tmp_path / "b", resume=True, progress=False)
    b.run(max_env_steps=80)
    (sa, meta_a), (sb, meta_b) = learner_state(a), learner_state(b)
    assert any(k.startswith("near.energy.") for k in sa) and any(k.startswith("optim.energy") for k in sa)
    assert sa.keys() == sb.keys()
    diff = [k for k in sa if not torch.equal(sa[k], sb[k])]
    assert not diff, diff[:5]
    assert meta_a == meta_b and meta_a["history"]   # the annealing state and the transform's history came back too


def test_discriminator_state_does_not_load_into_a_near_agent():
    cfg_d, cfg_n = toy_cfg("discriminator"), toy_cfg("near")
    for cfg in (cfg_d, cfg_n):
        cfg.model.obs_dim = cfg.model.action_dim = 2
    tensors, meta = FBCPRAgent(cfg_d.model, cfg_d.agent).state()
    with pytest.raises(CheckpointError, match="NEAR regulariser"):
        FBCPRAgent(cfg_n.model, cfg_n.agent).load_state(tensors, meta)


def test_bad_regulariser_is_a_config_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"agent\.regulariser: must be one of"):
        config_from_dict({"agent": {"regulariser": "energy"}})
    with pytest.raises(ConfigError, match=r"agent\.near\.sigma_min"):
        config_from_dict({"agent": {"regulariser": "near", "near": {"sigma_min": 2.0, "sigma_max": 1.0}}})
    assert config_from_dict({}).agent.regulariser == "discriminator"   # off by default


def test_energy_is_z_conditioned_and_annealing_reads_the_gap():
    """Two 'clips' at x = +1 and x = -1 under latents z_a and z_b: after DSM, each latent's energy prefers its own
    clip; online transitions moving toward the expert shrink the gap and anneal to a sharper level."""
    torch.manual_seed(0)
    cfg = NEARConfig(hidden_dim=32, hidden_layers=2, sigma_max=1.0, sigma_min=0.05, num_levels=4, ema=0.0,
                     transform=False, anneal_threshold=0.2)
    energy = ConditionalEnergy(obs_dim=2, z_dim=4, cfg=cfg)
    opt = torch.optim.Adam(energy.energy.parameters(), lr=3e-3)
    g = torch.Generator().manual_seed(0)
    z_a, z_b = torch.tensor([[2.0, 0, 0, 0]]), torch.tensor([[0, 2.0, 0, 0]])
    centre = torch.tensor([[1.0, 0.0], [-1.0, 0.0]])                                 # clip a, clip b

    def windows(n):  # (2n, 8, 2): n windows of each clip, each a short walk near its centre
        start = centre.repeat_interleave(n, 0)[:, None] + 0.1 * torch.randn(2 * n, 1, 2, generator=g)
        return start + 0.02 * torch.arange(8.0)[None, :, None]

    z_exp = torch.cat([z_a.expand(16, 4), z_b.expand(16, 4)])
    energy.step_normalizer.update(windows(16)[:, 1:] - windows(16)[:, :-1])
    for _ in range(250):
        w = windows(16)
        loss, _ = energy.expert_terms(w, w, z_exp, g)
        opt.zero_grad()
        loss.backward()
        opt.step()
        energy.step_ema()
    step = torch.full((2, 2), 0.02)
    anchor = torch.zeros(())
    r_a = energy.reward(centre, step, z_a.expand(2, 4), anchor)     # clip a's point, clip b's point under z_a
    r_b = energy.reward(centre, step, z_b.expand(2, 4), anchor)
    assert r_a[0] > r_a[1] + 1.0 and r_b[1] > r_b[0] + 1.0

    w = windows(16)
    _, expert = energy.expert_terms(w, w, z_exp, g)
    for offset in (1.5, 0.5, 0.0):  # phases whose online transitions end nearer and nearer clip a
        energy.observe(centre[:1].expand(8, 2) + offset, step[:1].expand(8, 2), z_a.expand(8, 4))
        stats = energy.end_phase(float(expert))
    assert energy.annealer.level >= 1 and stats["near/level"] == energy.annealer.level
    assert energy.history[0] < energy.history[-1] <= 0.5
