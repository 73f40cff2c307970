"""Kernels and ms per update of one source tree's learner, for comparing two trees run alternately (lab log 65).

    PYTHONPATH=TREE python lab/experiments/learner_before_after.py TREE LABEL [--sizes cpu cpu-bf16 small paper-S]

TREE is a checkout of this repository (its fbcpr package is the one imported, its benchmarks/update_speed.py draws
the batches); the kernels are counted with this tree's `fbcpr/nn/kernel_count.py`, loaded from its file so that the
other tree needs none. `cpu` is the shipped cpu config's agent (small networks, actor_std 0.05, action penalty 0.5)
in float32, `cpu-bf16` the same under `agent.bf16: true`.
"""
from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("kernel_count", HERE / "fbcpr" / "nn" / "kernel_count.py")
assert spec is not None and spec.loader is not None
kernel_count = importlib.util.module_from_spec(spec)
sys.modules["kernel_count"] = kernel_count
spec.loader.exec_module(kernel_count)

VARIANTS = {"cpu": ("small", {"actor_std": 0.05}, {"action_penalty": 0.5, "lr_b": 3e-5}, False),
            "cpu-bf16": ("small", {"actor_std": 0.05}, {"action_penalty": 0.5, "lr_b": 3e-5}, True),
            "small": ("small", {}, {"lr_b": 3e-5}, False), "paper-S": ("paper-S", {}, {}, False)}
BATCH = {"small": 256, "paper-S": 1024}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("tree")
    ap.add_argument("label")
    ap.add_argument("--sizes", nargs="+", default=list(VARIANTS))
    ap.add_argument("--reps", type=int, default=15)
    args = ap.parse_args()
    torch.set_num_threads(1)
    sys.path.insert(0, str(Path(args.tree) / "benchmarks"))
    from update_speed import ACT, OBS, draw

    import fbcpr
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.agent import FBCPRAgent
    assert Path(fbcpr.__file__).resolve().is_relative_to(Path(args.tree).resolve()), fbcpr.__file__
    for name in args.sizes:
        preset, model, agent_cfg, bf16 = VARIANTS[name]
        n = BATCH[preset]
        cfg = config_from_dict({"model": {"preset": preset, "obs_dim": OBS, "action_dim": ACT, **model},
                                "agent": {"batch_size": n, "bf16": bf16, **agent_cfg}})
        agent = FBCPRAgent(cfg.model, cfg.agent)
        batch, windows = draw(n, cfg.model.z_dim, 0)
        count = kernel_count.count_update_ops(agent, batch, windows)
        reps = args.reps if preset == "small" else 3
        times = []
        for _ in range(reps):
            t = time.perf_counter()
            agent.update(batch, windows)
            times.append(time.perf_counter() - t)
        print(f"{args.label:4s} {name:9s} kernels {count.kernels:5d} views {count.views:4d} ms best "
              f"{min(times) * 1e3:7.1f} median {statistics.median(times) * 1e3:7.1f} ({reps} updates)", flush=True)


if __name__ == "__main__":
    main()
