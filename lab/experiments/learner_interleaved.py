"""The learner's update against today's in one process, interleaved update by update (lab log 65).

    python lab/experiments/learner_interleaved.py [--sizes cpu cpu-bf16 small] [--updates 60]

Two agents from one seed on the same batch: `new` as the package builds it, `old` with what this tree changed put
back (torch's single-tensor Adam, as the CPU ran it before, and bf16 autocast casting each weight where it is used
instead of the bf16 weight copies). The layer-norm change is not undone (5% of the kernels). Updates alternate
between the two, so a busy machine slows both alike; the ratio of their median times is the speed-up.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from update_speed import ACT, OBS, draw  # noqa: E402

from fbcpr.core.config import config_from_dict  # noqa: E402
from fbcpr.methods.fb_cpr.agent import FBCPRAgent  # noqa: E402
from fbcpr.nn.kernel_count import count_update_kernels  # noqa: E402

VARIANTS = {"cpu": ("small", {"actor_std": 0.05}, {"action_penalty": 0.5, "lr_b": 3e-5}, False),
            "cpu-bf16": ("small", {"actor_std": 0.05}, {"action_penalty": 0.5, "lr_b": 3e-5}, True),
            "small": ("small", {}, {"lr_b": 3e-5}, False), "paper-S": ("paper-S", {}, {}, False)}


def build(name: str, old: bool) -> FBCPRAgent:
    preset, model, agent_cfg, bf16 = VARIANTS[name]
    n = 256 if preset == "small" else 1024
    cfg = config_from_dict({"model": {"preset": preset, "obs_dim": OBS, "action_dim": ACT, **model},
                            "agent": {"batch_size": n, "bf16": bf16, **agent_cfg}})
    agent = FBCPRAgent(cfg.model, cfg.agent)
    if old:
        for key, opt in agent.optimizers.items():
            agent.optimizers[key] = torch.optim.Adam(opt.param_groups[0]["params"], lr=opt.param_groups[0]["lr"],
                                                     foreach=False)
        agent._bf16_copies = lambda: None  # type: ignore[method-assign]
    return agent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", default=["cpu", "cpu-bf16", "small"])
    ap.add_argument("--updates", type=int, default=60)
    args = ap.parse_args()
    torch.set_num_threads(1)
    for name in args.sizes:
        agents = {"old": build(name, True), "new": build(name, False)}
        n = 256 if VARIANTS[name][0] == "small" else 1024
        batch, windows = draw(n, agents["new"].z_dim, 0)
        kernels = {k: count_update_kernels(a, batch, windows) for k, a in agents.items()}
        times: dict[str, list[float]] = {"old": [], "new": []}
        for _ in range(args.updates):
            for k, a in agents.items():
                t = time.perf_counter()
                a.update(batch, windows)
                times[k].append(time.perf_counter() - t)
        med = {k: statistics.median(v) for k, v in times.items()}
        print(f"{name:9s} kernels old {kernels['old']} new {kernels['new']} ({kernels['new'] / kernels['old']:.2f}x); "
              f"ms median old {med['old'] * 1e3:.1f} new {med['new'] * 1e3:.1f}; updates/s new/old "
              f"{med['old'] / med['new']:.2f} ({args.updates} interleaved updates each)", flush=True)


if __name__ == "__main__":
    main()
