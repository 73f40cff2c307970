"""Single-clip humanoid imitation on one protocol: TD3 on a learned imitation reward, scored next to random.

    python lab/experiments/imitation_humanoid.py --reward amp|near|virl|random [--clip walk] [--env-steps 23040]
                                            [--seeds 0,1] [--minutes 15] [--config PATH] [--out runs/imitation]

For each seed, one at a time: builds the run config as `fbcpr imitate CLIP --reward R` does (the shipped
`<reward>-walk` config, or --config, with env.motions = the clip; `--clip` is a name in data/clips/deepmimic or
a .npz path), sets the env-step budget, trains (stopping early, checkpointed, at --minutes of wall time), then
rolls the policy out deterministically from STARTS reference states spread over the clip (reference state
initialisation, as NEAR's evaluation) for HORIZON steps and scores each rollout against the clip: NEAR's DTW pose
error (root-relative body positions, metres), SPARC of the root speed next to the clip's own, and the seconds
until the pelvis first drops below 0.6 m (upright time; HORIZON / 30 s when it never does). A uniform random
policy is scored the same way in the same run (the floor); `--reward random` scores only the floor, no training.
One machine-readable line per seed, last:
    RESULT method=<reward> clip=<name> seed=<s> env_steps=<n> dtw=<x> sparc=<x> sparc_expert=<x> upright_s=<x>
           random_dtw=<x> random_sparc=<x> random_upright_s=<x> wall_s=<x> cpu_s=<x> ...
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

from fbcpr.cli.imitate_cmd import imitation_config
from fbcpr.core.config import data_dir
from fbcpr.core.protocols import EnvBundle
from fbcpr.envs.bundle import make_env
from fbcpr.eval.agents import RandomAgent
from fbcpr.inference.agents import make_agent
from fbcpr.metrics import imitation_scores
from fbcpr.eval.upright import seconds_upright
from fbcpr.train.trainer import Trainer

CLIPS = data_dir() / "clips" / "deepmimic"  # where `fbcpr motions import` puts them
STARTS, HORIZON = 8, 150


def score(agent: Any, bundle: EnvBundle) -> dict[str, float]:
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
    paths = np.stack(traj, 1)                                                   # (STARTS, HORIZON + 1, obs_dim)
    scores = [imitation_scores(p, clip.obs) for p in paths]
    upright = seconds_upright(paths[:, :-1, 0].T)   # first HORIZON frames: a fall seen only in the last one counts as none
    return {"dtw": float(np.mean([s["dtw"] for s in scores])), "sparc": float(np.mean([s["sparc"] for s in scores])),
            "sparc_expert": scores[0]["sparc_expert"], "upright_s": float(upright.mean())}


def clip_path(clip: str) -> Path:
    """A clip name of data/clips/deepmimic, or a path to a clip .npz."""
    path = Path(clip) if clip.endswith(".npz") else CLIPS / f"{clip}.npz"
    if not path.is_file():
        names = sorted(p.stem for p in CLIPS.glob("*.npz"))
        raise SystemExit(f"--clip: {path} is not a file; give a .npz or one of {names}")
    return path


def run_seed(reward: str, clip: Path, seed: int, env_steps: int, minutes: float, config: Optional[Path],
             out: Path) -> dict[str, Any]:
    """Train one seed (unless `reward` is random) and score it and the random floor."""
    cfg, _ = imitation_config(str(clip), "amp" if reward == "random" else reward, config)
    cfg.train.seed, cfg.train.total_env_steps = seed, env_steps
    cfg.train.warmup_steps = min(cfg.train.warmup_steps, env_steps // 2)
    torch.set_num_threads(cfg.train.torch_threads or 1)
    result: dict[str, Any] = {"method": reward, "clip": clip.stem, "seed": seed}
    if reward == "random":  # the floor alone, in the walk configs' env (same action mapping)
        bundle = make_env(cfg.env, 1, seed, 1)
        result.update({f"random_{k}": v for k, v in score(RandomAgent(seed), bundle).items()})
        bundle.env.close()
        return result
    t0, c0 = time.perf_counter(), time.process_time()
    trainer = Trainer(cfg, out, progress=False)
    try:
        summary = trainer.run(deadline=time.monotonic() + 60 * minutes)
    finally:
        trainer.close()
    result.update({"env_steps": summary["env_steps"], "updates": summary["updates"],
                   "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0})
    result.update(score(make_agent(summary["checkpoint"]), trainer.bundle))
    result.update({f"random_{k}": v for k, v in score(RandomAgent(seed), trainer.bundle).items() if k != "sparc_expert"})
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reward", required=True, choices=["amp", "near", "virl", "random"])
    ap.add_argument("--clip", default="walk", help="clip name in data/clips/deepmimic, or a .npz path")
    ap.add_argument("--env-steps", type=int, default=23040, help="env-step budget per seed")
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds, run one after another")
    ap.add_argument("--minutes", type=float, default=15.0, help="wall-clock cap on each seed's training")
    ap.add_argument("--config", type=Path, default=None, help="TD3 config instead of the shipped <reward>-walk")
    ap.add_argument("--out", type=Path, default=Path("runs/imitation"), help="parent of the run directories")
    args = ap.parse_args()
    clip = clip_path(args.clip)
    lines = []
    for seed in (int(s) for s in args.seeds.split(",")):
        out = args.out / f"{args.reward}-{clip.stem}-s{seed}"
        result = run_seed(args.reward, clip, seed, args.env_steps, args.minutes, args.config, out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "imitation.json").write_text(json.dumps(result, indent=1))
        lines.append("RESULT " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                          for k, v in result.items()))
        print(lines[-1], flush=True)
    if len(lines) > 1:  # all seeds together at the end, past the training logs
        print("\n".join(lines))


if __name__ == "__main__":
    main()
