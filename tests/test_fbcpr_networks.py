"""Batched-ensemble networks equal a per-member loop; output heads have the paper's ranges."""
import math

import pytest
import torch
import torch.nn.functional as F

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.nn.networks import EnsembleLinear, ZConditionedNet
from fbcpr.nn.normalizer import RunningNormalizer

torch.set_num_threads(1)


def _member(layer: EnsembleLinear, k: int, x: torch.Tensor) -> torch.Tensor:
    return F.linear(x, layer.weight[k].T, layer.bias[k, 0])


@pytest.mark.parametrize("shared", [True, False])
def test_ensemble_linear_equals_member_loop(shared):
    torch.manual_seed(0)
    layer = EnsembleLinear(5, 7, members=3)
    x = torch.randn(4, 5) if shared else torch.randn(3, 4, 5)
    y = layer(x)
    assert y.shape == (3, 4, 7)
    for k in range(3):
        xk = x if shared else x[k]
        torch.testing.assert_close(y[k], _member(layer, k, xk))


def _member_forward(net: ZConditionedNet, k: int, obs, extra, z):
    """Reference: the two-embedding architecture written out for member k with plain ops."""
    def stack(s, x, final_relu):
        for i, layer in enumerate(s.layers):
            x = _member(layer, k, x)
            last = i == len(s.layers) - 1
            if i == 0 and (not last or final_relu):
                x = torch.tanh(F.layer_norm(x, x.shape[-1:], s.norm.weight[k, 0], s.norm.bias[k, 0]))
            elif not last or final_relu:
                x = torch.relu(x)
        return x
    ex = stack(net.embed_x, torch.cat([obs, extra], -1), True)
    ez = stack(net.embed_z, torch.cat([obs, z], -1), True)
    h = torch.cat([ex, ez], -1)
    for layer in net.head.layers[:-1]:
        h = torch.relu(_member(layer, k, h))
    return _member(net.head.layers[-1], k, h)


def test_z_conditioned_ensemble_equals_member_loop():
    torch.manual_seed(1)
    net = ZConditionedNet(obs_dim=6, extra_dim=3, z_dim=4, out_dim=4, hidden=16, hidden_layers=2,
                          embedding_layers=3, members=2)
    for p in net.parameters():  # break the ones/zeros init of layernorm so members differ everywhere
        p.data.normal_()
    obs, a, z = torch.randn(5, 6), torch.randn(5, 3), torch.randn(5, 4)
    out = net(obs, a, z)
    for k in range(2):
        torch.testing.assert_close(out[k], _member_forward(net, k, obs, a, z), rtol=1e-5, atol=1e-5)
    # a precomputed (s, z) embedding gives the same output (the sharing used by the agent)
    torch.testing.assert_close(net(obs, a, z, pre=net.precompute(obs, z)), out)


def test_model_heads():
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}}).model
    model = FBCPRModel(cfg)
    obs = torch.randn(50, 6) * 10
    z = model.sample_z(50)
    torch.testing.assert_close(z.norm(dim=-1), torch.full((50,), math.sqrt(cfg.z_dim)))
    b = model.backward(obs)
    torch.testing.assert_close(b.norm(dim=-1), torch.full((50,), math.sqrt(cfg.z_dim)))
    a = model.act(obs, z, mean=False)
    assert a.shape == (50, 3) and a.abs().max() <= 1.0
    d = model.discriminator(model.normalize(obs), z)
    assert ((d > 0) & (d < 1)).all()
    assert model.forward_map(obs, a, z).shape == (cfg.ensemble_size, 50, cfg.z_dim)
    assert model.critic(obs, a, z).shape == (cfg.ensemble_size, 50, 1)
    a_np = model.act(obs.numpy(), z.numpy())
    assert a_np.shape == (50, 3) and not torch.is_tensor(a_np)
    with pytest.raises(ValueError, match="obs: expected shape"):
        model.act(torch.randn(2, 5), z[:2])


def test_normalizer_matches_numpy_over_batches():
    torch.manual_seed(0)
    norm = RunningNormalizer(3)
    xs = [torch.randn(n, 3) * 4 + 2 for n in (5, 17, 1, 40)]
    for x in xs:
        norm.update(x)
    allx = torch.cat(xs).double()
    torch.testing.assert_close(norm.mean, allx.mean(0))
    torch.testing.assert_close(norm.var, allx.var(0, unbiased=False))
    y = norm(torch.cat(xs))
    torch.testing.assert_close(y.mean(0), torch.zeros(3), atol=1e-5, rtol=0)
