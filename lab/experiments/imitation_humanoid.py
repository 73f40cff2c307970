"""Single-clip humanoid imitation on one protocol: TD3 on a learned imitation reward, scored next to random.

    python lab/experiments/imitation_humanoid.py --reward amp|near|virl|random [--clip walk] [--env-steps 23040]
                                            [--seeds 0,1] [--minutes 15] [--config PATH] [--out runs/imitation]
    python lab/experiments/imitation_humanoid.py --run RUN_DIR [--clip walk] [--every 1] [--sheet PNG] [--plot PNG]
                                            [--sheet-steps 150]

For each seed, one at a time: builds the run config as `fbcpr imitate CLIP --reward R` does (the shipped
`<reward>-walk` config, or --config, with env.motions = the clip; `--clip` is a name in data/clips/deepmimic or
a .npz path), sets the env-step budget, trains (stopping early, checkpointed, at --minutes of wall time), then
rolls the policy out deterministically from STARTS reference states spread over the clip (reference state
initialisation, as NEAR's evaluation) for HORIZON steps and scores each rollout against the clip: NEAR's DTW pose
error (root-relative body positions, metres), SPARC of the root speed next to the clip's own, and the seconds
until the pelvis first drops below 0.6 m (upright time; HORIZON / 30 s when it never does). A uniform random
policy is scored the same way in the same run (the floor); `--reward random` scores only the floor, no training.
`--run` trains nothing: it scores every `--every`-th checkpoint of a run made with `fbcpr imitate` (a long one,
continued with `--resume`), one RESULT line each, with the zero-action floor beside random's; `--plot` draws the
curve and `--sheet` a contact sheet of the last checkpoint's rollout from the clip's first frame beside the clip.
One machine-readable line per seed, last:
    RESULT method=<reward> clip=<name> seed=<s> env_steps=<n> dtw=<x> sparc=<x> sparc_expert=<x> upright_s=<x>
           random_dtw=<x> random_sparc=<x> random_upright_s=<x> wall_s=<x> cpu_s=<x> ...
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fbcpr.cli.imitate_cmd import imitation_config
from fbcpr.core.checkpoint import list_checkpoints, load_checkpoint
from fbcpr.core.config import data_dir
from fbcpr.core.protocols import EnvBundle
from fbcpr.envs.bundle import make_env
from fbcpr.eval.agents import RandomAgent, ZeroAgent
from fbcpr.eval.upright import seconds_upright
from fbcpr.inference.agents import make_agent
from fbcpr.metrics import imitation_scores
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
    upright = seconds_upright(paths[:, :-1, 0].T)  # first HORIZON frames: a fall seen only in the last counts as none
    return {"dtw": float(np.mean([s["dtw"] for s in scores])), "sparc": float(np.mean([s["sparc"] for s in scores])),
            "sparc_expert": scores[0]["sparc_expert"], "upright_s": float(upright.mean())}


def clip_path(clip: str) -> Path:
    """A clip name of data/clips/deepmimic, or a path to a clip .npz."""
    path = Path(clip) if clip.endswith(".npz") else CLIPS / f"{clip}.npz"
    if not path.is_file():
        names = sorted(p.stem for p in CLIPS.glob("*.npz"))
        raise SystemExit(f"--clip: {path} is not a file; give a .npz or one of {names}")
    return path


def run_seed(reward: str, clip: Path, seed: int, env_steps: int, minutes: float, config: Path | None,
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
    floor = score(RandomAgent(seed), trainer.bundle)
    result.update({f"random_{k}": v for k, v in floor.items() if k != "sparc_expert"})
    return result


class _One:
    """One observation in, one action out, for the single-env rollout of the contact sheet."""

    def __init__(self, agent: Any) -> None:
        self.agent, self.action_mapping = agent, getattr(agent, "action_mapping", "rest")

    def act(self, obs: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.asarray(self.agent.act(obs[None], np.zeros((1, 0), np.float32), mean=True))[0]


def score_run(run: Path, clip: Path, every: int, sheet: Path | None, plot: Path | None,
              sheet_steps: int = HORIZON) -> list[str]:
    """RESULT lines of every `every`-th checkpoint of `run` (and its last), floors once; the curve and sheet."""
    found = list_checkpoints(run / "checkpoints")
    if not found:
        raise SystemExit(f"--run: {run} has no checkpoints/step_* folders")
    picked = sorted(set(found[::every]) | {found[-1]})
    cfg = load_checkpoint(picked[-1]).config
    cfg.env.motions = str(clip.resolve())
    bundle = make_env(cfg.env, 1, cfg.train.seed, 1)
    try:
        floors = {name: score(agent, bundle) for name, agent in (("random", RandomAgent(0)), ("zero", ZeroAgent()))}
        rows = []
        for ckpt in picked:
            row = {"method": cfg.agent.reward.imitation, "clip": clip.stem, "seed": cfg.train.seed,
                   "env_steps": int(ckpt.name.split("_")[-1]), **score(make_agent(str(ckpt)), bundle)}
            row.update({f"{f}_{k}": v for f, got in floors.items() for k, v in got.items() if k != "sparc_expert"})
            row["dtw_vs_random"] = row["dtw"] / row["random_dtw"]
            rows.append(row)
            print("RESULT " + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                  flush=True)
    finally:
        bundle.env.close()
    (run / "imitation_curve.json").write_text(json.dumps(rows, indent=1))
    if plot is not None:
        _plot(rows, plot)
    if sheet is not None:
        _sheet(picked[-1], clip, sheet, sheet_steps)
    return [f"{r['env_steps']}: dtw {r['dtw']:.3f} ({r['dtw_vs_random']:.2f}x random), upright {r['upright_s']:.1f} s"
            for r in rows]


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    """DTW and upright seconds against env steps, the random and zero-action floors dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [r["env_steps"] for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for ax, key, label in ((axes[0], "dtw", "DTW pose error (m)"), (axes[1], "upright_s", "upright (s)")):
        ax.plot(steps, [r[key] for r in rows], "o-", label=rows[0]["method"])
        for floor, style in (("random", "--"), ("zero", ":")):
            ax.axhline(rows[0][f"{floor}_{key}"], color="gray", linestyle=style, label=f"{floor} action")
        ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1e3:.0f}k")
        ax.set_xlabel("env steps"), ax.set_ylabel(label)
    axes[0].legend()
    fig.suptitle(f"{rows[0]['method']} imitating {rows[0]['clip']}, seed {rows[0]['seed']}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _sheet(ckpt: Path, clip_file: Path, path: Path, steps: int) -> None:
    """The last checkpoint from the clip's first frame, body beside clip, next to the zero action's rollout."""
    from contact_sheet import contact_sheet  # a sibling lab script: its folder is first on sys.path

    from fbcpr.cli.prompt_cmd import rollout
    from motions.clip import load_clip

    clip = load_clip(clip_file)
    zs, start = np.zeros((steps, 0), np.float32), (clip.qpos[0], clip.qvel[0])
    rows = [(f"{label} (left) beside {clip_file.stem} (right)",
             rollout(_One(agent), zs, start=start, video=True, reference=clip, label=label), True)
            for label, agent in ((ckpt.name, make_agent(str(ckpt))), ("zero action", ZeroAgent()))]
    path.parent.mkdir(parents=True, exist_ok=True)
    contact_sheet(rows, max(1, min(15, steps // 10))).save(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reward", choices=["amp", "near", "virl", "random"], help="train and score (or --run)")
    ap.add_argument("--run", type=Path, default=None, help="score the checkpoints of this `fbcpr imitate` run")
    ap.add_argument("--every", type=int, default=1, help="with --run: every N-th checkpoint (and the last)")
    ap.add_argument("--sheet", type=Path, default=None, help="with --run: contact sheet PNG of the last checkpoint")
    ap.add_argument("--plot", type=Path, default=None, help="with --run: PNG of the curve against env steps")
    ap.add_argument("--sheet-steps", type=int, default=HORIZON, help="with --sheet: steps of its rollouts")
    ap.add_argument("--clip", default="walk", help="clip name in data/clips/deepmimic, or a .npz path")
    ap.add_argument("--env-steps", type=int, default=23040, help="env-step budget per seed")
    ap.add_argument("--seeds", default="0", help="comma-separated training seeds, run one after another")
    ap.add_argument("--minutes", type=float, default=15.0, help="wall-clock cap on each seed's training")
    ap.add_argument("--config", type=Path, default=None, help="TD3 config instead of the shipped <reward>-walk")
    ap.add_argument("--out", type=Path, default=Path("runs/imitation"), help="parent of the run directories")
    args = ap.parse_args()
    clip = clip_path(args.clip)
    if (args.run is None) == (args.reward is None):
        raise SystemExit("give --reward (train and score) or --run (score a run's checkpoints)")
    if args.run is not None:
        print("\n".join(score_run(args.run, clip, args.every, args.sheet, args.plot, args.sheet_steps)))
        return
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
