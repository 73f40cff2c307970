"""The async training engine (`train.engine: async`) next to the sync loop, on the same machine, config and ratio.

    python benchmarks/engine_speed.py [--device cpu|cuda] [--quick] [--preset P] [--collectors N] [--envs N]
    python benchmarks/engine_speed.py --scaling [--quick]      # collection alone: 1 collector against 2

Each engine trains the same config (the humanoid on the synthetic clips, the paper's ratio of 1 update per 10 env
steps, no evaluations or checkpoints in between) through `fbcpr.train.trainer.Trainer`; rates come from the run's
own metrics.csv rows (`wall_s`, `env_steps`, `updates`) between the first row a phase after the warm-up and the
last, so the start of the collector processes and the random warm-up are left out. samples/s = updates/s x batch.
The last line:

    RESULT engine device=cpu|cuda samples_per_s=N env_steps_per_s=N ratio_vs_sync=X kernels_per_update=N
    kernels_per_update_sync=M

ratio_vs_sync is the engine's samples/s over the sync loop's (the ratio of updates to env steps is the same in both).
On the CPU the engine's learner is compiled (`agent.compile`; `--no-compile` runs it eagerly), and its first phase of
updates, where it compiles, is among those left out; the sync loop's is today's eager learner. kernels_per_update counts
the engine's learner, kernels_per_update_sync the sync loop's, both on the CPU (`fbcpr.nn.kernel_count`).

`--scaling`: a stand-in learner that does no work (updates_per_rollout 0) and collectors on one MuJoCo thread each;
env steps/s of 1 and of 2 collectors (the same envs in all, split between them), the ratio 2 collectors / 1
collector, one collector stepping the same envs on 2 MuJoCo threads (`train.env_threads: 2`: the cores used by
threads, not processes; collector_threads_2_vs_1 against 1 collector on one thread), and as references the sync
loop's on one MuJoCo thread and on two.
"""
from __future__ import annotations

import argparse
import csv
import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from fbcpr.core.config import config_from_dict
from fbcpr.core.schema import Config
from fbcpr.nn.kernel_count import count_compiled_update, count_update_kernels
from fbcpr.train.trainer import Trainer

#: batch per network size: the shipped CPU configs' and the paper's
BATCH = {"tiny": 32, "small": 256, "paper-S": 1024, "paper-M": 1024}


def engine_config(args: argparse.Namespace, engine: str, collectors: int, updates: int, warmup: int,
                  steps: int) -> Config:
    """The benchmark's run: `steps` env steps after `warmup`, updates_per_rollout `updates` per rollout_steps."""
    cuda = args.device == "cuda"
    return config_from_dict({
        "model": {"preset": args.preset},
        "agent": {"batch_size": BATCH[args.preset], "seq_length": 8, "cuda_graph": cuda, "bf16": False,
                  "compile": args.compile and engine == "async"},
        "env": {"name": "humanoid", "motions": "synthetic", "max_episode_steps": 300, "action_mapping": "rest",
                "fall_prob": 0.2, "stand_prob": 0.3},
        "train": {"device": args.device, "engine": engine, "collectors": collectors, "num_envs": args.envs,
                  "total_env_steps": warmup + steps, "warmup_steps": warmup, "rollout_steps": args.rollout,
                  "updates_per_rollout": updates, "buffer_capacity": max(warmup + steps, BATCH[args.preset]),
                  "device_buffer": cuda, "priority_every": 0, "eval_every": 0, "checkpoint_every": 0,
                  "log_every": args.rollout, "reward_buffer_size": 0, "save_buffer": False, "seed": 0,
                  "torch_threads": args.threads, "env_threads": args.env_threads if engine == "sync" else 0},
    })


def rows(run_dir: Path) -> list[dict[str, float]]:
    """metrics.csv as one dict per logged env step."""
    by_step: dict[int, dict[str, float]] = {}
    with open(run_dir / "metrics.csv") as f:
        for rec in csv.DictReader(f):
            by_step.setdefault(int(rec["env_steps"]), {})[rec["key"]] = float(rec["value"])
    return [dict(v, env_steps=float(k)) for k, v in sorted(by_step.items())]


def measure(cfg: Config, out: Path, skip: int) -> dict[str, float]:
    """Train `cfg` to its end; env steps/s and updates/s between the first log row at >= `skip` env steps and the
    last."""
    tr = Trainer(cfg, out, progress=False)
    try:
        tr.run()
    finally:
        tr.close()
    logged = [r for r in rows(out) if r["env_steps"] >= skip and "wall_s" in r]
    first, last = logged[0], logged[-1]
    dt = last["wall_s"] - first["wall_s"]
    return {"env_steps_per_s": (last["env_steps"] - first["env_steps"]) / dt,
            "updates_per_s": (last["updates"] - first["updates"]) / dt, "seconds": dt}


def kernels_per_update(preset: str, compiled: bool) -> int:
    """Kernels one update of the learner launches at `preset`'s size and batch, counted on the CPU after one uncounted
    update (`fbcpr.nn.kernel_count`): eager, the aten operators that launch work (views and metadata apart) of its
    forward, backward and optimisers; compiled (`agent.compile`), the kernels inductor generated for the CPU plus the
    operators called outside them."""
    from update_speed import make  # the update benchmark's agent and random humanoid batch at this size

    agent, batch, windows = make(preset, "cpu", compiled)
    return count_compiled_update(agent, batch, windows).kernels if compiled else count_update_kernels(agent, batch,
                                                                                                         windows)


def compare(args: argparse.Namespace, tmp: Path) -> None:
    warmup, steps = args.warmup, args.steps
    updates = args.rollout // 10  # the paper's ratio: 1 update per 10 env steps
    # counted first: the engine's learner then reuses the code compiled here (with the counter's profiler markers)
    sync_kernels = kernels_per_update(args.preset, False)
    kernels = kernels_per_update(args.preset, True) if args.compile else sync_kernels
    skip = warmup + args.rollout
    out: dict[str, dict[str, float]] = {}
    for engine, collectors in (("sync", 1), ("async", args.collectors)):
        cfg = engine_config(args, engine, collectors, updates, warmup, steps)
        out[engine] = r = measure(cfg, tmp / engine, skip)
        print(f"{engine:5s} collectors={collectors if engine == 'async' else '-'} envs={args.envs} "
              f"{r['env_steps_per_s']:,.0f} env steps/s {r['updates_per_s']:.2f} updates/s "
              f"({r['seconds']:.1f} s measured)", flush=True)
    batch = BATCH[args.preset]
    a, s = out["async"], out["sync"]
    print(f"RESULT engine device={args.device} samples_per_s={a['updates_per_s'] * batch:.0f} "
          f"env_steps_per_s={a['env_steps_per_s']:.0f} ratio_vs_sync={a['updates_per_s'] / s['updates_per_s']:.2f} "
          f"kernels_per_update={kernels} kernels_per_update_sync={sync_kernels}")


def scaling(args: argparse.Namespace, tmp: Path) -> None:
    """Collection alone (a learner that does no work): 1 and 2 collectors of one thread each, and the sync loop."""
    steps = args.steps
    found: dict[str, float] = {}
    # (engine, name, collectors, MuJoCo threads: of the sync loop, or of each collector)
    runs = [("sync", "sync (1 thread)", 1, 1), ("sync", "sync (2 threads)", 1, 2), ("async", "1 collector", 1, 1),
            ("async", "2 collectors", 2, 1), ("async", "1 collector, 2 threads", 1, 2)]
    for engine, name, collectors, threads in runs:
        cfg = engine_config(args, engine, collectors, 0, 0, steps)
        cfg.train.env_threads = threads
        found[name] = r = measure(cfg, tmp / name.replace(" ", "_"), args.rollout * 4)
        print(f"{name:22s} envs={args.envs} {r['env_steps_per_s']:,.0f} env steps/s ({r['seconds']:.1f} s measured)",
              flush=True)
    one = found["1 collector"]["env_steps_per_s"]
    ratio, threaded = found["2 collectors"]["env_steps_per_s"] / one, found["1 collector, 2 threads"]["env_steps_per_s"]
    print(f"RESULT collection device=cpu collectors_2_vs_1={ratio:.2f} collector_threads_2_vs_1={threaded / one:.2f} "
          f"one_collector_env_steps_per_s={found['1 collector']['env_steps_per_s']:.0f} "
          f"two_collectors_env_steps_per_s={found['2 collectors']['env_steps_per_s']:.0f} "
          f"sync_one_thread_env_steps_per_s={found['sync (1 thread)']['env_steps_per_s']:.0f} "
          f"sync_two_threads_env_steps_per_s={found['sync (2 threads)']['env_steps_per_s']:.0f} "
          f"cores={os.cpu_count()} load1={os.getloadavg()[0]:.1f}")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    p.add_argument("--quick", action="store_true", help="fewer steps (within 10 minutes on 2 cores)")
    p.add_argument("--scaling", action="store_true", help="collection alone: 1 collector against 2")
    p.add_argument("--preset", default=None, help="network size (default: small on cpu, paper-S on cuda)")
    p.add_argument("--collectors", type=int, default=None, help="async collectors (default: cores - 1, at least 1)")
    p.add_argument("--envs", type=int, default=None, help="envs in all (default: 16, or 8 per collector on cuda)")
    p.add_argument("--warmup", type=int, default=None, help="random warm-up env steps (default: two phases, at "
                   "least a batch)")
    p.add_argument("--steps", type=int, default=None, help="env steps measured after the warm-up (default: 10 "
                   "phases, --quick; else 40; --scaling: 4 times as many)")
    p.add_argument("--rollout", type=int, default=None, help="env steps per rollout phase, updates a tenth "
                   "(default: 10 vector steps of the envs)")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the learner")
    p.add_argument("--compile", action=argparse.BooleanOptionalAction, default=None,
                   help="the engine's learner compiled (agent.compile; default: on the CPU; a GPU graphs it instead)")
    p.add_argument("--env-threads", type=int, default=0, help="MuJoCo threads of the sync loop (0: all cores)")
    args: Any = p.parse_args(argv)
    cores = os.cpu_count() or 1
    args.preset = args.preset or ("paper-S" if args.device == "cuda" else "small")
    args.compile = args.device == "cpu" if args.compile is None else args.compile
    if args.compile and args.device == "cuda":
        raise SystemExit("--compile: on cuda the engine's learner runs in a CUDA graph (agent.cuda_graph) instead")
    args.collectors = args.collectors or (2 if args.scaling else max(1, cores - 1))
    args.envs = args.envs or (8 * args.collectors if args.device == "cuda" else 16)
    args.rollout = args.rollout or 10 * args.envs
    args.warmup = args.warmup if args.warmup is not None else max(2 * args.rollout, BATCH[args.preset])
    args.steps = args.steps or (10 if args.quick else 40) * args.rollout * (4 if args.scaling else 1)
    if args.device == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: CUDA is not available")
    torch.set_num_threads(args.threads)
    print(f"engine_speed: device={args.device} preset={args.preset} batch={BATCH[args.preset]} envs={args.envs} "
          f"cores={cores} load1={os.getloadavg()[0]:.1f} torch {torch.__version__}", flush=True)
    with tempfile.TemporaryDirectory(prefix="engine_speed_") as tmp:
        (scaling if args.scaling else compare)(args, Path(tmp))


if __name__ == "__main__":
    main()
