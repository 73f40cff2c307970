"""Zero-shot tracking of the held-out split, clip by clip: how far from the clip, next to a body frozen in its
first pose, and how it fails (lab/log.md 63).

For each clip, `fbcpr track`'s rollout (z_t from the clip's next states, from the clip's first state) and:
- MPJPE: mean over steps and the 23 bodies of the distance between the body's and the clip's positions relative
  to the pelvis, in the heading frame (the observation's own body positions); EMD (`fbcpr.metrics.emd`); each
  beside the first-pose floor (the clip's first pose held still, `hold_first_pose_emd`'s body);
- fall: the first step the pelvis is below FALLEN_HEIGHT while the clip's is above it, and whether it is still
  down at the end; the MPJPE and its floor over the steps before it (how it tracked while it was up);
- lag: the delay (0-1 s) at which the body's poses best match the clip's earlier ones, and how much that delay
  lowers the MPJPE;
- drift: the pelvis's horizontal distance from the clip's at the end.
The verdict reads these in order: falls, lags (a delay of 3+ steps that lowers the error by 15%+), or stays up in
the wrong pose (error above 0.8 of the floor), else tracks.

    python lab/experiments/heldout_tracking.py pretrained --split lab/splits/heldout-tracking.txt \\
        --clips data/clips/cmu-all --seed 6303 --out runs/s63/heldout.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from tracking_split import clip_file, read_split  # the sibling script: the split's lists and clip files

from fbcpr import BFM
from fbcpr.cli.prompt_cmd import rollout
from fbcpr.eval.runner import hold_first_pose, hold_first_pose_emd
from fbcpr.metrics import emd, mpjpe
from humanoid_env.env import FALLEN_HEIGHT
from humanoid_env.model import CONTROL_HZ
from motions.clip import Clip, load_clip

MAX_LAG = 30  # steps: 1 s


def best_lag(agent: np.ndarray, ref: np.ndarray) -> tuple[int, float]:
    """(delay in steps, MPJPE at it): the body at t against the clip at t - delay."""
    scores = [mpjpe(agent[k:], ref[:len(agent) - k]) for k in range(min(MAX_LAG, len(agent) // 2) + 1)]
    k = int(np.argmin(scores))
    return k, scores[k]


def diagnose(agent: Any, clip: Clip, seed: int) -> dict:
    """The measures above for any tracking agent (a `BFM`, an NPMP's `NPMPAgent`): z_t from its `track_z` of the
    clip's observations."""
    zs = agent.track_z(clip.obs)
    ep = rollout(agent, zs, seed=seed, start=(clip.qpos[0], clip.qvel[0]), label=f"track {clip.name}")
    n = min(len(ep.obs), clip.n_frames)
    agent, ref, qpos = np.stack(ep.obs)[:n], clip.obs[:n], np.stack(ep.qpos)[:n]
    frozen = hold_first_pose(clip)[:n]
    err, floor = mpjpe(agent, ref), mpjpe(frozen, ref)
    down = (agent[:, 0] < FALLEN_HEIGHT) & (ref[:, 0] >= FALLEN_HEIGHT)
    fell_at = int(np.argmax(down)) if down.any() else None
    up = slice(0, max(fell_at or n, 2))  # the steps before the fall: how it tracked while it was up
    lag, lagged = best_lag(agent, ref)
    out = {"clip": clip.name, "seconds": round(clip.seconds, 2), "mpjpe": round(err, 4), "mpjpe_floor": round(floor, 4),
           "emd": round(emd(agent, clip.obs), 4), "emd_floor": round(hold_first_pose_emd(clip), 4),
           "fell_at_s": None if fell_at is None else round(fell_at / CONTROL_HZ, 2),
           "down_at_end": bool(agent[-1, 0] < FALLEN_HEIGHT <= ref[-1, 0]),
           "lag_steps": lag, "mpjpe_at_lag": round(lagged, 4),
           "drift_m": round(float(np.linalg.norm(qpos[-1, :2] - clip.qpos[len(qpos) - 1, :2])), 3),
           "clip_travel_m": round(float(np.linalg.norm(clip.qpos[-1, :2] - clip.qpos[0, :2])), 3),
           "diverged": ep.diverged_at is not None,
           "mpjpe_while_up": round(mpjpe(agent[up], ref[up]), 4),
           "floor_while_up": round(mpjpe(frozen[up], ref[up]), 4)}
    out["mpjpe_ratio"] = round(err / floor, 3)
    out["emd_ratio"] = round(out["emd"] / out["emd_floor"], 3)
    if fell_at is not None:
        out["verdict"] = f"falls at {out['fell_at_s']:.1f} s" + ("" if out["down_at_end"] else ", gets up")
    elif lag >= 3 and lagged < 0.85 * err:
        out["verdict"] = f"lags {lag / CONTROL_HZ:.1f} s"
    elif err > 0.8 * floor:
        out["verdict"] = "upright, wrong pose"
    else:
        out["verdict"] = "tracks"
    return out


def summarise(rows: list[dict]) -> dict:
    """Means over clips of the MPJPE, EMD and their floors, the ratios of the means, and the count of falls."""
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("mpjpe", "mpjpe_floor", "emd", "emd_floor")}
    return {**mean, "mpjpe_ratio": mean["mpjpe"] / mean["mpjpe_floor"], "emd_ratio": mean["emd"] / mean["emd_floor"],
            "falls": sum(r["fell_at_s"] is not None for r in rows), "clips": len(rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--split", type=Path, default=Path("lab/splits/heldout-tracking.txt"))
    ap.add_argument("--clips", type=Path, default=Path("data/clips/cmu-all"))
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    rows = []
    for take in read_split(args.split):
        row = diagnose(bfm, load_clip(clip_file(take, args.clips)), args.seed)
        row["take"] = take
        rows.append(row)
        print(json.dumps(row), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"checkpoint": args.checkpoint, "seed": args.seed, "clips": rows}, indent=2))
    print("| take | s | MPJPE (m) | floor | ratio | EMD | floor | ratio | verdict | ratio while up | lag (steps) | "
          "drift / clip travel (m) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---|")
    for r in rows:
        print(f"| {r['take'].removeprefix('cmu/')} | {r['seconds']:.1f} | {r['mpjpe']:.3f} | {r['mpjpe_floor']:.3f} | "
              f"{r['mpjpe_ratio']:.2f} | {r['emd']:.2f} | {r['emd_floor']:.2f} | {r['emd_ratio']:.2f} | "
              f"{r['verdict']} | {r['mpjpe_while_up'] / r['floor_while_up']:.2f} | {r['lag_steps']} | "
              f"{r['drift_m']:.1f} / {r['clip_travel_m']:.1f} |")
    mean = summarise(rows)
    print(f"mean: MPJPE {mean['mpjpe']:.3f} / floor {mean['mpjpe_floor']:.3f} = {mean['mpjpe_ratio']:.2f}x;"
          f" EMD {mean['emd']:.2f} / floor {mean['emd_floor']:.2f} = {mean['emd_ratio']:.2f}x; "
          f"falls {mean['falls']} of {len(rows)}")


if __name__ == "__main__":
    main()
