"""The learner's fewer-kernel update computes the update it replaced: torch's reference Adam (one tensor at a time)
and the layer norm's separate affine give the same weights within float32 rounding, on the same batches and seed."""
from __future__ import annotations

import pytest
import torch
from test_fbcpr_agent import make_agent, make_batch

from fbcpr.nn.kernel_count import count_ops, count_update_ops
from fbcpr.nn.networks import EnsembleLayerNorm

torch.set_num_threads(1)


def reference_adam(agent) -> None:
    """Swap the agent's optimisers for torch's single-tensor Adam over the same parameters and learning rates (the
    update as it was)."""
    for name, opt in agent.optimizers.items():
        group = opt.param_groups[0]
        agent.optimizers[name] = torch.optim.Adam(group["params"], lr=group["lr"], betas=(0.9, 0.999), eps=1e-8,
                                                  foreach=False)


def weights(agent) -> torch.Tensor:
    return torch.cat([p.detach().flatten() for p in agent.model.parameters()]
                     + [p.detach().flatten() for p in agent.targets.parameters()])


@pytest.mark.parametrize("options", [{}, {"action_penalty": 0.5}, {"regulariser": "near"}])
def test_update_equals_the_reference_update(options):
    new, old = make_agent(**options), make_agent(**options)
    reference_adam(old)
    for step in range(4):
        batch, windows = make_batch(new, seed=step)
        m_new, m_old = new.update(batch, windows), old.update(batch, windows)
        for key in m_old:
            assert m_new[key] == pytest.approx(m_old[key], rel=1e-4, abs=1e-5), (step, key)
    w_new, w_old = weights(new), weights(old)
    assert not torch.equal(w_new, weights(make_agent(**options)))  # the weights did move
    torch.testing.assert_close(w_new, w_old, rtol=1e-4, atol=1e-6)


def test_every_optimiser_steps_in_one_fused_kernel():
    agent = make_agent()
    count = count_update_ops(agent, *make_batch(agent))
    assert count.ops["aten._fused_adam_.default"] == len(agent.optimizers)
    assert count.ops["aten.addcdiv_.default"] == 0  # no per-parameter step left


def test_one_member_layer_norm_equals_the_separate_affine():
    torch.manual_seed(0)
    norm = EnsembleLayerNorm(16, members=1)
    with torch.no_grad():
        norm.weight.normal_()
        norm.bias.normal_()
    x = torch.randn(1, 32, 16, requires_grad=True)
    out = norm(x)
    ref = torch.addcmul(norm.bias, torch.nn.functional.layer_norm(x, (16,)), norm.weight)
    torch.testing.assert_close(out, ref)
    g = torch.randn_like(out)
    grads = torch.autograd.grad(out, (x, norm.weight, norm.bias), g)
    ref_grads = torch.autograd.grad(ref, (x, norm.weight, norm.bias), g)
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b)
    assert count_ops(lambda: norm(x)).kernels == 1


def test_a_state_saved_by_the_reference_adam_resumes_fused():
    """A checkpoint written before the fused optimiser loads into it, keeps its moments and steps fused."""
    old = make_agent()
    reference_adam(old)
    batch, windows = make_batch(old)
    old.update(batch, windows)
    tensors, meta = old.state()
    assert meta["optimizers"]["actor"]["param_groups"][0]["fused"] is not True
    new = make_agent()
    new.model.load_state_dict(old.model.state_dict())
    new.load_state(tensors, meta)
    for name, opt in new.optimizers.items():
        assert opt.param_groups[0]["fused"] is True
        p = opt.param_groups[0]["params"][0]
        torch.testing.assert_close(opt.state[p]["exp_avg"], old.optimizers[name].state[p_old(old, name)]["exp_avg"])
    count = count_update_ops(new, batch, windows, warmup=0)
    assert count.ops["aten._fused_adam_.default"] == len(new.optimizers)


def p_old(agent, name: str) -> torch.Tensor:
    return agent.optimizers[name].param_groups[0]["params"][0]


def test_bf16_weight_copies_give_autocasts_gradients_with_fewer_casts():
    """The bf16 copies refreshed once per step compute what bf16 autocast alone computed, casting far less."""
    copies, auto = make_agent(bf16=True), make_agent(bf16=True)
    auto._bf16_copies = lambda: None  # autocast casting each weight where it is used, as before the copies
    batch, windows = make_batch(copies)
    copies.backward(batch, windows)
    auto.backward(batch, windows)
    for name, opt in copies.optimizers.items():
        for p, q in zip(opt.param_groups[0]["params"], auto.optimizers[name].param_groups[0]["params"]):
            assert p.grad is not None and p.grad.dtype == torch.float32
            torch.testing.assert_close(p.grad, q.grad, rtol=1e-2, atol=1e-4)
    casts = count_update_ops(copies, batch, windows).ops["aten._to_copy.default"]
    assert casts < count_update_ops(auto, batch, windows).ops["aten._to_copy.default"] / 2
    assert all(p.dtype == torch.float32 for p in copies.model.parameters())  # the masters stay float32


def test_backward_map_runs_in_float32_under_bf16_autocast():
    """Sigma_B's solve amplifies B's rounding, so B ignores autocast."""
    agent = make_agent()
    obs = torch.randn(16, 6)
    plain = agent.model.backward_map(obs)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = agent.model.backward_map(obs)
        assert agent.model.forward_map(obs, torch.zeros(16, 3), plain).dtype == torch.bfloat16  # autocast is on
    assert under.dtype == torch.float32
    torch.testing.assert_close(under, plain)


def test_two_member_pessimism_equals_the_pairwise_formula():
    from fbcpr.nn.ensemble_td import pessimistic

    v = torch.randn(2, 64, requires_grad=True)
    for coef in (0.25, 0.5, 1.0):
        ref = v.mean(0) - coef * (v.unsqueeze(0) - v.unsqueeze(1)).abs().sum((0, 1)) / 2
        got = pessimistic(v, coef)
        torch.testing.assert_close(got, ref)
        torch.testing.assert_close(torch.autograd.grad(got.sum(), v)[0], torch.autograd.grad(ref.sum(), v)[0])
