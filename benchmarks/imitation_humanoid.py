"""Single-clip humanoid imitation at a CPU budget: train a TD3 imitation config, then score it next to random.

    python benchmarks/imitation_humanoid.py configs/near-walk.yaml [--seed 0] [--minutes 15] [--out runs/...]

Trains the config (stopping early at --minutes of wall time), then rolls the policy out deterministically from
STARTS reference states spread over the clip (reference state initialisation, as NEAR's evaluation) for HORIZON
steps, and scores each rollout against the clip: NEAR's DTW pose error (root-relative body positions, metres),
SPARC of the root speed next to the clip's own, and the seconds until the pelvis first drops below 0.6 m (upright
time; HORIZON / 30 s when it never does). The uniform random policy is scored the same way. Last line:
    RESULT method=<reward> clip=<name> dtw=<x> sparc=<x> sparc_expert=<x> upright_s=<x> random_dtw=<x> ...
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fbcpr.config import load_config
from fbcpr.evaluation.agents import RandomAgent, make_agent
from fbcpr.evaluation.metrics import imitation_scores
from fbcpr.evaluation.upright import FALLEN
from fbcpr.trainer import Trainer
from humanoid_env.model import CONTROL_HZ

STARTS, HORIZON = 8, 150


def score(agent: Any, bundle: Any) -> dict[str, float]:
    """Mean DTW, SPARC and upright seconds of `agent` from STARTS clip states, against the (single) clip."""
    clip = bundle.library.clips[0]
    frames = np.linspace(0, clip.n_frames - 2, STARTS).astype(int)
    env = bundle.make_eval_env(STARTS, HORIZON + 1)
    try:
        obs, _ = env.reset(seed=0, options={"qpos": clip.qpos[frames], "qvel": clip.qvel[frames]})
        traj = [obs]
        for _ in range(HORIZON):
            obs, *_ = env.step(agent.act(obs, np.zeros((STARTS, 0), np.float32), mean=True))
            traj.append(obs)
    finally:
        env.close()
    paths = np.stack(traj, 1)                                                   # (STARTS, HORIZON + 1, 358)
    scores = [imitation_scores(p, clip.obs) for p in paths]
    down = paths[:, :, 0] < FALLEN
    upright = np.where(down.any(1), down.argmax(1), HORIZON) / CONTROL_HZ
    return {"dtw": float(np.mean([s["dtw"] for s in scores])), "sparc": float(np.mean([s["sparc"] for s in scores])),
            "sparc_expert": scores[0]["sparc_expert"], "upright_s": float(upright.mean())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--minutes", type=float, default=15.0, help="wall-clock cap on training")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    cfg = load_config(args.config)
    cfg.train.seed = args.seed
    torch.set_num_threads(cfg.train.torch_threads or 1)
    out = Path(args.out or f"runs/{Path(args.config).stem}-s{args.seed}")
    t0, c0 = time.perf_counter(), time.process_time()
    trainer = Trainer(cfg, out, progress=False)
    summary = trainer.run(deadline=time.monotonic() + 60 * args.minutes)
    cost = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "env_steps": trainer.env_steps}
    learned = score(make_agent(summary["checkpoint"]), trainer.bundle)
    floor = score(RandomAgent(args.seed), trainer.bundle)
    result = {"method": cfg.agent.reward.imitation, "clip": trainer.bundle.library.names[0], **learned,
              **{f"random_{k}": v for k, v in floor.items()}, **cost}
    (out / "imitation.json").write_text(json.dumps(result, indent=1))
    print("RESULT " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in result.items()))


if __name__ == "__main__":
    main()
