"""Milliseconds per update with its batch drawn on the host or on the device (`train.device_buffer`).

    python benchmarks/batch_draw.py [--sizes small paper-S] [--rows 100000] [--updates 50] [--graph] [--threads 2]

Each row runs `--updates` FB-CPR updates back to back, as the trainer does between two rollouts, each on a batch
drawn just before it, and waits for the device once at the end:
- `host`: the replay batch gathered by numpy from a `ReplayBuffer` and the demonstration windows from the
  `MotionLibrary`, then copied to the device (the default);
- `device`: both drawn by `fbcpr.train.device_batches.DeviceBatches` from its device copies;
- `update only`, the reference measured in the same run: the same updates on one batch already on the device.
The `draw` column times the draw alone. The buffer holds `--rows` random humanoid-sized transitions (obs 358,
action 69) and the windows come from the clips in `--motions`. On a GPU, `--graph` adds the rows with the update
captured in a CUDA graph (`agent.cuda_graph`), where the draw is what is left besides the replay.
"""
from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import torch

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.train.buffer import ReplayBuffer, transition_specs
from fbcpr.train.device_batches import DeviceBatches
from motions.library import MotionLibrary

SIZES = {"tiny": 256, "small": 256, "paper-S": 1024}
OBS, ACT, NQ, NV = 358, 69, 76, 75


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def filled_buffer(rows: int, z_dim: int, seed: int = 0) -> ReplayBuffer:
    """A buffer of `rows` random transitions, written in chunks as rollouts write them."""
    specs = transition_specs(OBS, ACT, z_dim, NQ, NV)
    buf = ReplayBuffer(rows, specs)
    rng = np.random.default_rng(seed)
    for start in range(0, rows, 10_000):
        k = min(10_000, rows - start)
        buf.add({name: rng.standard_normal((k, *shape), dtype=np.float32) for name, shape in specs.items()})
    return buf


def per_update(run: Callable[[], None], device: torch.device, updates: int, reps: int) -> float:
    """Best over `reps` of: `updates` calls of `run`, then one wait for the device; seconds per call."""
    for _ in range(3):  # warm-up (a graphed update captures on its 4th call)
        run()
    sync(device)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        for _ in range(updates):
            run()
        sync(device)
        best = min(best, (time.perf_counter() - t) / updates)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["small", "paper-S"], choices=sorted(SIZES))
    ap.add_argument("--rows", type=int, default=100_000, help="transitions in the replay buffer")
    ap.add_argument("--updates", type=int, default=50, help="updates per timed run (the trainer's per rollout)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--motions", default="data/clips/deepmimic", help="folder of clips for the windows")
    ap.add_argument("--graph", action="store_true", help="also with the update in a CUDA graph (GPU only)")
    ap.add_argument("--cpu", action="store_true", help="time on the CPU even where a GPU is present")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    if args.rows < 1 or args.updates < 1 or args.reps < 1:
        ap.error("--rows, --updates and --reps must be >= 1")
    torch.set_num_threads(args.threads)
    device = torch.device("cuda" if torch.cuda.is_available() and not args.cpu else "cpu")
    library = MotionLibrary.load(args.motions)
    rng = np.random.default_rng(0)
    print(f"torch {torch.__version__}, {device}" + (f" ({torch.cuda.get_device_name()})" if device.type == "cuda"
          else f", {args.threads} threads") + f", {args.rows:,} transitions, {args.updates} updates per run")
    print(f"{'size':8s} {'batch':>5s} {'update':8s} {'draw from':12s} {'draw ms':>8s} {'ms/update':>10s} "
          f"{'vs update only':>15s}")
    for preset in args.sizes:
        n = SIZES[preset]
        cfg = config_from_dict({"model": {"preset": preset, "obs_dim": OBS, "action_dim": ACT},
                                "agent": {"batch_size": n}})
        buf = filled_buffer(args.rows, cfg.model.z_dim)
        fields = FBCPRAgent.fields
        batches = DeviceBatches(buf, library, fields, device, seed=0)
        windows, length = n // cfg.agent.seq_length, cfg.agent.seq_length

        def host() -> tuple[dict, torch.Tensor]:
            batch = buf.sample(rng, n, fields=fields)
            w = torch.as_tensor(library.sample_windows(rng, windows, length))
            return {k: v.to(device) for k, v in batch.items()}, w.to(device)

        def on_device() -> tuple[dict, torch.Tensor]:
            return batches.sample(n, windows, length)

        graphs = [False, True] if args.graph and device.type == "cuda" else [False]
        for graph in graphs:
            agent = FBCPRAgent(cfg.model, config_from_dict({"agent": {"batch_size": n, "cuda_graph": graph}}).agent,
                               device=device)
            fixed = on_device()
            alone = per_update(lambda: agent.update(*fixed), device, args.updates, args.reps)
            label = "graphed" if graph else "eager"
            print(f"{preset:8s} {n:5d} {label:8s} {'update only':12s} {'':>8s} {alone * 1e3:10.2f} {'1.00':>15s}",
                  flush=True)
            for name, draw in (("device", on_device), ("host", host)):
                draw_s = per_update(draw, device, args.updates, args.reps)
                total = per_update(lambda: agent.update(*draw()), device, args.updates, args.reps)
                print(f"{preset:8s} {n:5d} {label:8s} {name:12s} {draw_s * 1e3:8.2f} {total * 1e3:10.2f} "
                      f"{total / alone:15.2f}", flush=True)


if __name__ == "__main__":
    main()
