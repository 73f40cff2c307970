"""Agent update: gradients reach only the intended networks, Polyak targets, z sampling proportions."""
import copy
import math

import pytest
import torch

from fbcpr.methods.fb_cpr.agent import TARGETS, FBCPRAgent
from fbcpr.core.config import config_from_dict

torch.set_num_threads(1)
NETS = ("forward_map", "backward_map", "actor", "critic", "discriminator")


def make_agent(**agent):
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3},
                            "agent": {"batch_size": 32, **agent}})
    return FBCPRAgent(cfg.model, cfg.agent, seed=0)


def make_batch(agent, n=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    batch = {"obs": torch.randn(n, 6, generator=g), "action": torch.rand(n, 3, generator=g) * 2 - 1,
             "next_obs": torch.randn(n, 6, generator=g), "z": agent.model.sample_z(n, g),
             "terminated": (torch.rand(n, generator=g) < 0.2).float()}
    return batch, torch.randn(n // 8, 8, 6, generator=g) + 1.0


EXPECTED = {
    "fb_loss": {"forward_map", "backward_map"},
    "fz_loss": {"forward_map"},
    "ortho_loss": {"backward_map"},
    "critic_loss": {"critic"},
    "actor_loss": {"actor"},
    "disc_loss": {"discriminator"},
    "grad_penalty": {"discriminator"},
}


@pytest.mark.parametrize("loss_name", sorted(EXPECTED))
def test_gradients_reach_only_intended_networks(loss_name):
    agent = make_agent()
    batch, windows = make_batch(agent)
    out = agent._losses(batch["obs"], batch["action"], batch["next_obs"], batch["z"], batch["terminated"], windows)
    reached = set()
    for net in NETS:
        params = list(getattr(agent.model, net).parameters())
        grads = torch.autograd.grad(out[loss_name], params, retain_graph=True, allow_unused=True)
        if any(g is not None and g.abs().sum() > 0 for g in grads):
            reached.add(net)
    assert reached == EXPECTED[loss_name]
    # the targets never receive gradients
    assert not any(p.requires_grad for p in agent.targets.parameters())


def test_update_changes_every_network_and_polyak_targets():
    agent = make_agent()
    batch, windows = make_batch(agent)
    before = {k: copy.deepcopy(getattr(agent.model, k).state_dict()) for k in NETS}
    tgt_before = copy.deepcopy(agent.targets.state_dict())
    metrics = agent.update(batch, windows)
    assert all(math.isfinite(v) for v in metrics.values())
    for k in NETS:
        after = getattr(agent.model, k).state_dict()
        assert any(not torch.equal(before[k][n], after[n]) for n in after), k
    tau = agent.cfg.tau
    for name, new_t in agent.targets.state_dict().items():
        net, pname = name.split(".", 1)
        online = getattr(agent.model, net).state_dict()[pname]
        torch.testing.assert_close(new_t, (1 - tau) * tgt_before[name] + tau * online, rtol=1e-6, atol=1e-7)
    assert set(TARGETS) == {"forward_map", "backward_map", "critic"}


def _classify(z, markers):
    """Index of the marker each row equals (-1 when none: a fresh uniform draw)."""
    hits = torch.stack([(z == m).all(-1) for m in markers], -1)
    return torch.where(hits.any(-1), hits.float().argmax(-1), torch.full((len(z),), -1))


def test_nu_mixture_and_relabel_proportions():
    agent = make_agent()
    d, n = agent.model.cfg.z_dim, 40_000
    eye = torch.eye(d) * math.sqrt(d)
    online_b, expert_z, orig = eye[0].expand(100, d), eye[1].expand(7, d), eye[2].expand(n, d)
    lab = _classify(agent.sample_z(n, online_b, expert_z), [eye[1], eye[0]])
    tol = 4 * math.sqrt(0.25 / n)
    assert abs((lab == 0).float().mean().item() - 0.6) < tol      # ER_FB of demonstrations
    assert abs((lab == 1).float().mean().item() - 0.2) < tol      # B of online states
    assert abs((lab == -1).float().mean().item() - 0.2) < tol     # uniform on the sphere
    z = agent.relabel(orig, online_b, expert_z)
    lab = _classify(z, [eye[2], eye[1], eye[0]])
    for k, p in ((0, 0.2), (1, 0.8 * 0.6), (2, 0.8 * 0.2), (-1, 0.8 * 0.2)):
        assert abs((lab == k).float().mean().item() - p) < tol, k
    torch.testing.assert_close(z.norm(dim=-1), torch.full((n,), math.sqrt(d)))
    # without demonstrations or online data, everything is uniform
    assert (_classify(agent.sample_z(1000, None, None), [eye[0], eye[1]]) == -1).all()


def test_update_is_deterministic_given_seed():
    a1, a2 = make_agent(), make_agent()
    batch, windows = make_batch(a1)
    m1, m2 = a1.update(batch, windows), a2.update(batch, windows)
    assert m1 == m2


def test_bf16_switch_trains_in_float32_master_weights():
    agent = make_agent(bf16=True)
    batch, windows = make_batch(agent)
    before = copy.deepcopy(agent.model.forward_map.state_dict())
    metrics = agent.update(batch, windows)
    assert all(math.isfinite(v) for v in metrics.values())
    after = agent.model.forward_map.state_dict()
    assert all(v.dtype == torch.float32 for v in after.values())
    assert any(not torch.equal(before[k], after[k]) for k in after)


def test_bf16_auto_follows_the_measured_speed(monkeypatch):
    from fbcpr.nn import precision

    cpu = torch.device("cpu")
    assert precision.matmul_seconds(torch.float32, cpu, size=64, repeats=1) > 0
    assert precision.resolve_bf16(True, cpu) is True and precision.resolve_bf16(False, cpu) is False
    for bf16_time, expected in ((0.2, True), (5.0, False)):
        monkeypatch.setattr(precision, "matmul_seconds", lambda dtype, device: bf16_time if dtype == torch.bfloat16 else 1.0)
        assert precision.resolve_bf16("auto", cpu) is expected


def test_bf16_setting_is_validated():
    from fbcpr.core.config import config_from_dict
    from fbcpr.core.errors import ConfigError

    assert config_from_dict({"agent": {"bf16": "auto"}}).agent.bf16 == "auto"
    with pytest.raises(ConfigError, match="agent.bf16"):
        config_from_dict({"agent": {"bf16": "fast"}})
