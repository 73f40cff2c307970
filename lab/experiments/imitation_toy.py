"""Single-task and imitation evidence on the point mass: TD3 on one reward; AMP, NEAR and VIRL on one demonstration.

    python lab/experiments/imitation_toy.py [--out runs/imitation-toy] [--seed 0] [--steps N] [--only td3,amp,near,virl-state,virl-video]
                                       [--set agent.virl.multitask=null ...]   (ablations: config overrides)

Trains fbcpr/configs/td3-toy.yaml (TD3 on the reach-top-right reward) and fbcpr/configs/amp-toy.yaml (TD3 on the AMP reward
of the circle-ccw demonstration), each in well under 3 CPU minutes, and evaluates them next to a uniform random
policy: TD3 by its task's return (fbcpr.eval.toy.task_return), AMP by NEAR's average DTW position error to
the demonstration (and SPARC, next to the demonstration's). fbcpr/configs/near-toy.yaml trains TD3 on the NEAR energy
of the same demonstration at the same budget, scored the same way. fbcpr/configs/virl-toy.yaml and virl-toy-video.yaml train
TD3 on VIRL's comparator reward (states, and the toy rendered as 32x32 frames) at AMP's budget and are scored
the same way, plus the share of the demo's shape reproduced (`shape_coverage`). The last lines are machine-readable, one per method:
    RESULT method=<name> task=<task> metric=<metric> value=<x> random=<y>
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

import yaml

from fbcpr.core.config import config_from_dict, find_config
from fbcpr.core.schema import Config
from fbcpr.eval.toy import imitation_metrics, task_return
from fbcpr.train.trainer import Trainer

EVAL_SEED = 123
IMITATION = {"amp": "amp-toy", "near": "near-toy", "virl-state": "virl-toy",
             "virl-video": "virl-toy-video"}


def load(config: str, overrides: tuple[str, ...]) -> Config:
    """A shipped toy config with `dotted.key=value` overrides (YAML values), validated like any config."""
    data = yaml.safe_load(find_config(config).read_text())
    for item in overrides:
        key, _, value = item.partition("=")
        *path, last = key.split(".")
        node = data
        for name in path:
            node = node.setdefault(name, {})
        node[last] = yaml.safe_load(value)
    return config_from_dict(data)


def train(config: str, out: Path, seed: int, overrides: tuple[str, ...] = (),
          steps: int | None = None) -> tuple[Trainer, dict[str, float]]:
    """Train one config to its end (or `steps` env steps); returns the trainer and its wall / CPU seconds."""
    cfg = load(config, overrides)
    cfg.train.seed = seed
    if steps is not None:
        cfg.train.total_env_steps, cfg.train.warmup_steps = steps, min(cfg.train.warmup_steps, steps // 2)
    torch.set_num_threads(cfg.train.torch_threads or 1)
    t0, c0 = time.perf_counter(), time.process_time()
    trainer = Trainer(cfg, out, progress=False)
    trainer.run()
    return trainer, {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="runs/imitation-toy")
    ap.add_argument("--steps", type=int, help="env steps of every run (default: each config's own)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="td3," + ",".join(IMITATION), help="comma-separated methods to run")
    ap.add_argument("--set", action="append", default=[], help="config override for the imitation runs, key=value")
    args = ap.parse_args()
    out = Path(args.out)
    only = args.only.split(",")
    results = []

    if "td3" in only:
        td3, cost = train("td3-toy", out / "td3", args.seed, steps=args.steps)
        task = td3.cfg.agent.reward.task
        value = task_return(td3.agent.model.eval(), task, np.random.default_rng(EVAL_SEED), prompt=False)
        random = task_return(None, task, np.random.default_rng(EVAL_SEED), prompt=False)
        results.append({"method": "td3", "task": task, "metric": "return", "value": value, "random": random, **cost})

    for method in (m for m in IMITATION if m in only):
        run, cost = train(IMITATION[method], out / method, args.seed, tuple(args.set), args.steps)
        demo = run.cfg.env.motions
        learned = imitation_metrics(run.agent.model.eval(), demo, np.random.default_rng(EVAL_SEED))
        floor = imitation_metrics(None, demo, np.random.default_rng(EVAL_SEED))
        results.append({"method": method, "task": demo, "metric": "dtw", "value": learned["dtw"],
                        "random": floor["dtw"], "shape": learned["shape_coverage"],
                        "shape_random": floor["shape_coverage"], "sparc": learned["sparc"],
                        "sparc_random": floor["sparc"], "sparc_expert": learned["sparc_expert"], **cost})

    out.mkdir(parents=True, exist_ok=True)
    (out / f"results-seed{args.seed}.json").write_text(json.dumps(results, indent=1))
    for r in results:
        extra = {k: round(v, 3) for k, v in r.items() if k not in ("method", "task", "metric", "value", "random")}
        print(f"{r['method']}: {json.dumps(extra)}")
    for r in results:
        print(f"RESULT method={r['method']} task={r['task']} metric={r['metric']} value={r['value']:.4g} "
              f"random={r['random']:.4g}")


if __name__ == "__main__":
    main()
