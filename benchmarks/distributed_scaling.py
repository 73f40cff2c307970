"""Env steps/s and updates/s of data-parallel training on 1 and more ranks (torchrun, gloo on CPU), with the scaling
efficiency rate(N) / (N x rate(1)); the 1-rank rows are the reference, measured in the same run.

    python benchmarks/distributed_scaling.py [--config cpu] [--ranks 1 2] [--collect-steps 8192] [--train-steps 3072]

Each world size runs `torchrun --standalone --nproc_per_node=N -m fbcpr train` twice on a copy of the config (its
model, batch, envs per rank and update ratio; no checkpoints, evaluations or priority refreshes in between):
  collect  only the random warm-up (no updates): env steps/s of N ranks stepping their own envs;
  train    a short warm-up, then rollouts and updates at the config's update-to-data ratio, gradients averaged
           over the ranks each update: env steps/s and updates/s of the whole loop (global counts).
Rates are the trainer's own (summary.json: steps over the seconds of `Trainer.run`, start-up excluded). Each rank
uses train.torch_threads (1 in the shipped CPU configs), so N ranks want N free cores. Last, the time of one gloo
all-reduce of the model's gradient size over N ranks (what each update adds), measured apart.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from fbcpr.core.config import find_config, load_config
from fbcpr.core.registry import get_method
from fbcpr.core.schema import dump_config

ROOT = Path(__file__).resolve().parents[1]


def run(config: Path, ranks: int, steps: int, warmup: int, out: Path) -> dict:
    """One torchrun of `steps` global env steps; the run's summary.json."""
    cfg = load_config(config)
    tc = cfg.train
    tc.total_env_steps, tc.warmup_steps = steps, warmup
    tc.checkpoint_every = tc.priority_every = tc.eval_every = 0
    tc.eval_upright, tc.eval_tasks, tc.eval_at_start, tc.keep_best = 0, [], False, ""  # no evaluations: none of theirs
    tc.keep_best_requires = {}
    tc.log_every, tc.reward_buffer_size, tc.save_buffer = 10**9, 0, False
    tc.buffer_capacity = min(tc.buffer_capacity, 2 * steps)
    path = out / f"{config.stem}.yaml"
    path.write_text(dump_config(cfg))
    if (out / "run").exists():
        shutil.rmtree(out / "run")
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={ranks}", "-m", "fbcpr",
           "train", str(path), "--out", str(out / "run"), "--no-progress"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1", "GOMP_SPINCOUNT": "0"}
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return json.loads((out / "run" / "summary.json").read_text())


def _allreduce_worker(rank: int, world: int, port: int, numel: int, repeats: int, out: str) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.set_num_threads(1)
    dist.init_process_group("gloo", rank=rank, world_size=world)
    flat = torch.randn(numel)
    dist.all_reduce(flat)  # connections up
    t0 = time.perf_counter()
    for _ in range(repeats):
        dist.all_reduce(flat)
    if rank == 0:
        Path(out).write_text(str((time.perf_counter() - t0) / repeats))
    dist.destroy_process_group()


def allreduce_ms(world: int, numel: int, repeats: int = 20) -> float:
    """Milliseconds of one gloo all-reduce of `numel` float32 (the flat gradient of one update) over `world` ranks."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.NamedTemporaryFile() as f:
        mp.spawn(_allreduce_worker, args=(world, port, numel, repeats, f.name), nprocs=world, join=True)
        return 1000 * float(Path(f.name).read_text())


def trainable_parameters(cfg) -> int:
    """Parameters the update reduces gradients of (the humanoid's dimensions; counted on the meta device)."""
    model_cfg = replace(cfg.model, obs_dim=cfg.model.obs_dim or 358, action_dim=cfg.model.action_dim or 69)
    with torch.device("meta"):
        return sum(p.numel() for p in get_method(cfg.algorithm).model(model_cfg).parameters() if p.requires_grad)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="cpu", help="shipped config name or YAML path (default: cpu)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--collect-steps", type=int, default=8192)
    ap.add_argument("--train-steps", type=int, default=3072)
    args = ap.parse_args()
    config = find_config(args.config)
    cfg = load_config(config)
    batch = cfg.agent.batch_size
    print(f"config {config.name}: {cfg.train.num_envs} envs per rank, local batch {batch}, "
          f"{cfg.train.updates_per_rollout} updates per {cfg.train.rollout_steps} env steps; "
          f"{os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.ranks:
            collect = run(config, n, args.collect_steps, args.collect_steps, Path(tmp))
            # warm-up: every rank's shard needs one batch before the first update
            train = run(config, n, args.train_steps, n * batch, Path(tmp))
            rows.append((n, collect["env_steps"] / collect["seconds"], train["env_steps"] / train["seconds"],
                         train["updates"] / train["seconds"], train["updates"]))
            print(f"  {n} rank(s) done, load average {os.getloadavg()[0]:.1f}", flush=True)
    base = rows[0]
    print(f"\n{'ranks':>5} {'global batch':>12} {'collect steps/s':>16} {'train steps/s':>14} {'updates/s':>10} "
          f"{'samples/s':>10} {'updates':>8} {'eff. collect':>12} {'eff. updates':>12}")
    for n, c, t, u, nu in rows:
        scale = n / base[0]
        print(f"{n:>5} {n * batch:>12} {c:>16,.0f} {t:>14,.0f} {u:>10.2f} {u * n * batch:>10,.0f} {nu:>8} "
              f"{c / (scale * base[1]):>12.2f} {u / (scale * base[3]):>12.2f}")
    print("\nefficiency = rate(N) / (N x rate(1 rank)); updates/s counts global updates, each on N x the local batch "
          "(samples/s = updates/s x global batch)")
    numel = trainable_parameters(cfg)
    for n in args.ranks:
        if n > 1:
            print(f"gradient all-reduce, {numel:,} float32 over {n} gloo ranks: {allreduce_ms(n, numel):.1f} ms "
                  f"per update, against {1000 / base[3]:.0f} ms per update of the 1-rank loop (env steps included)")


if __name__ == "__main__":
    main()
