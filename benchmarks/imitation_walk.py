"""Single-demonstration imitation on the humanoid: train an imitation config, score it next to a random policy.

    python benchmarks/imitation_walk.py [configs/virl-walk.yaml] [--out runs/virl-walk] [--seed 0] [--episodes 8]
                                        [--max-minutes M]

Trains the config (TD3 on an imitation reward of one clip, e.g. configs/virl-walk.yaml; amp-walk / near-walk run
the same way) and evaluates the policy and a uniform random one from the same starts: `episodes` rollouts from
frames of the clip spread over its length, each 3 clip lengths long, scored against the clip tiled from that
frame (the DeepMimic walk is a cycle) by NEAR's DTW pose error and SPARC (fbcpr.evaluation.metrics), plus the
upright time under no prompt (fbcpr.evaluation.upright, standing and fall starts). Last line, machine-readable:
    RESULT method=<reward> clip=<name> dtw=<x> dtw_random=<y> sparc=<s> sparc_expert=<e> upright_s=<u> ...
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from fbcpr.config import load_config
from fbcpr.evaluation.agents import Agent, make_agent
from fbcpr.evaluation.metrics import imitation_scores
from fbcpr.evaluation.upright import upright
from fbcpr.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
CYCLES = 3


def clip_rollouts(agent: Agent, clip: object, episodes: int, action_mapping: str) -> list[dict[str, float]]:
    """Imitation scores of `episodes` rollouts from frames of the clip (CYCLES clip lengths each)."""
    from humanoid_env.vector import VectorHumanoidEnv

    T = len(clip.obs)  # type: ignore[attr-defined]
    starts = np.linspace(0, T - 1, episodes).astype(int)
    steps = CYCLES * T
    env = VectorHumanoidEnv(episodes, max_episode_steps=steps + 1, action_mapping=action_mapping)
    try:
        obs, _ = env.reset(options={"qpos": clip.qpos[starts], "qvel": clip.qvel[starts]})  # type: ignore[attr-defined]
        traj = [obs]
        z = np.zeros((episodes, 0), np.float32)
        for _ in range(steps - 1):
            obs, *_ = env.step(agent.act(obs, z))
            traj.append(obs)
    finally:
        env.close()
    paths = np.stack(traj, 1)
    tiled = np.concatenate([clip.obs] * (CYCLES + 1))  # type: ignore[attr-defined]
    return [imitation_scores(p, tiled[s: s + steps]) for p, s in zip(paths, starts)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?", default=str(ROOT / "configs" / "virl-walk.yaml"))
    ap.add_argument("--out", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--max-minutes", type=float, default=None, help="stop training early (checkpointed) after this")
    args = ap.parse_args()
    cfg = load_config(args.config)
    cfg.train.seed = args.seed
    out = Path(args.out or ROOT / "runs" / Path(args.config).stem)
    torch.set_num_threads(cfg.train.torch_threads or 1)
    t0, c0 = time.perf_counter(), time.process_time()
    trainer = Trainer(cfg, out, progress=False)
    summary = trainer.run(deadline=None if args.max_minutes is None else time.monotonic() + 60 * args.max_minutes)
    trainer.close()
    cost = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    clip = trainer.bundle.library.clips[0]
    mapping = cfg.env.action_mapping
    result: dict[str, object] = {"method": cfg.agent.reward.imitation, "clip": clip.name, "env_steps": summary["env_steps"],
                                 "updates": summary["updates"], **cost}
    for name, agent in (("", make_agent(summary["checkpoint"])), ("_random", make_agent("random", seed=args.seed))):
        scores = clip_rollouts(agent, clip, args.episodes, mapping)
        up = upright(agent, episodes=args.episodes, steps=150, seed=args.seed)
        result.update({f"dtw{name}": float(np.mean([s["dtw"] for s in scores])),
                       f"sparc{name}": float(np.mean([s["sparc"] for s in scores])),
                       f"upright_s{name}": up.median_seconds, f"got_up{name}": up.share_got_up})
        result["sparc_expert"] = float(np.mean([s["sparc_expert"] for s in scores]))
    (out / f"imitation-seed{args.seed}.json").write_text(json.dumps(result, indent=1))
    print("RESULT " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in result.items()))


if __name__ == "__main__":
    main()
