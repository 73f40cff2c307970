"""The kernel counter: what it counts (forward, backward, optimiser; views apart) and that an update's count is
stable."""
from __future__ import annotations

import torch

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.nn.kernel_count import (INDUCTOR_KERNEL, count_launches, count_ops, count_update_kernels,
                                   count_update_ops)
from fbcpr.nn.networks import project_sphere


def test_views_are_kept_apart_from_kernels() -> None:
    x, y = torch.randn(4, 3), torch.randn(4, 3)
    add = count_ops(lambda: x + y)
    assert (add.kernels, add.views) == (1, 0)
    view = count_ops(lambda: x.view(-1))
    assert (view.kernels, view.views) == (0, 1)
    assert view.total == 1


def test_backward_and_optimiser_ops_are_counted() -> None:
    w = torch.randn(3, requires_grad=True)
    x = torch.randn(5, 3)
    forward = count_ops(lambda: (x * w).sum())
    both = count_ops(lambda: (x * w).sum().backward())
    assert both.kernels > forward.kernels
    assert both.ops["aten.mul.Tensor"] >= 2  # x * w, and the backward's grad * x
    opt = torch.optim.Adam([w], foreach=False)
    opt.step()  # creates the state
    step = count_ops(opt.step)
    assert step.ops["aten.addcdiv_.default"] == 1 and step.kernels >= 4


def tiny_agent(seed: int = 0) -> tuple[FBCPRAgent, dict[str, torch.Tensor], torch.Tensor]:
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 12, "action_dim": 4},
                            "agent": {"batch_size": 32}})
    agent = FBCPRAgent(cfg.model, cfg.agent, seed=seed)
    g = torch.Generator().manual_seed(seed)
    batch = {"obs": torch.randn(32, 12, generator=g), "action": torch.rand(32, 4, generator=g) * 2 - 1,
             "next_obs": torch.randn(32, 12, generator=g),
             "z": project_sphere(torch.randn(32, cfg.model.z_dim, generator=g)), "terminated": torch.zeros(32)}
    return agent, batch, torch.randn(4, 8, 12, generator=g)


def test_update_count_covers_forward_backward_and_step_and_is_stable() -> None:
    agent, batch, windows = tiny_agent()
    count = count_update_ops(agent, batch, windows)
    assert agent.num_updates == 2  # one warm-up, one counted
    assert count.ops["aten.native_layer_norm_backward.default"] > 0  # backward
    assert count.ops["aten._foreach_lerp_.Scalar"] >= 1  # Polyak
    assert count.kernels > count.ops["aten.baddbmm.default"] > 0
    again = count_update_kernels(*tiny_agent(seed=1))
    assert again == count.kernels  # the same graph of operators whatever the seed


def test_the_profiler_count_equals_the_dispatch_count_on_an_eager_update() -> None:
    agent, batch, windows = tiny_agent()
    agent.update(batch, windows)
    by_dispatch = count_ops(lambda: agent.update(batch, windows))
    by_profiler = count_launches(lambda: agent.update(batch, windows))
    assert by_profiler.kernels == by_dispatch.kernels
    assert by_profiler.ops["aten::_fused_adam_"] == by_dispatch.ops["aten._fused_adam_.default"] > 0


def test_an_inductor_kernel_counts_once_by_its_marker() -> None:
    """What inductor's C++ kernels look like to the profiler under `kernel_markers` (compiling one here would take
    half a minute on a cold cache: `benchmarks/update_speed.py --compile` counts a real compiled update)."""
    x, w = torch.randn(8, 16), torch.randn(16, 16)

    def wrapper() -> torch.Tensor:  # a compiled graph's wrapper: an external matmul, then one fused kernel
        y = torch.mm(x, w)
        with torch.profiler.record_function("graph_0_cpp_fused_add_mul_relu_tanh_0"):
            return torch.tanh(y * 2.0 + 1.0).relu()  # inside the kernel: not operators of their own

    count = count_launches(wrapper)
    assert count.kernels == 2
    assert count.ops["aten::mm"] == count.ops["graph_0_cpp_fused_add_mul_relu_tanh_0"] == 1
    assert INDUCTOR_KERNEL.match("graph_0_cpp_fused_add_mul_relu_tanh_0")
    assert not INDUCTOR_KERNEL.match("aten::mm")
