"""The kernel counter: what it counts (forward, backward, optimiser; views apart) and that an update's count is
stable."""
from __future__ import annotations

import torch

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.nn.kernel_count import count_ops, count_update_kernels, count_update_ops
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
