"""Tracking refined by rollouts (`fbcpr track --refine`) against zero-shot tracking and the first-pose floor, per clip.

For each clip: the zero-shot rollout (B-given z's, one batched env of one, from the clip's first state), the refined
one (`fbcpr.inference.track_refine`), and a body frozen in the first pose. Per clip: MPJPE (pelvis-relative, every
body) and EMD of each, whether the body stays up to the clip's end (no frame where its pelvis is below the fallen
height while the reference's is above it, no divergence), and the refinement's seconds of compute per second of
motion with the load average around it (the machine is shared).

    python lab/experiments/track_refine_heldout.py data/clips/heldout/*.npz --candidates 32 --out runs/trk.json
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from fbcpr.eval.runner import hold_first_pose
from fbcpr.inference.bfm import BFM
from fbcpr.inference.prompt import load_motion
from fbcpr.inference.track_refine import Receding
from fbcpr.metrics import emd, mpjpe
from humanoid_env.env import FALLEN_HEIGHT
from humanoid_env.vector import VectorHumanoidEnv


def zero_shot(bfm: BFM, clip, zs: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """(obs, qpos, diverged) of the B-given z's rolled out from the clip's first state."""
    env = VectorHumanoidEnv(1, max_episode_steps=len(zs) + 1, num_threads=1, action_mapping=bfm.action_mapping)
    o, info = env.reset(options={"qpos": clip.qpos[:1], "qvel": clip.qvel[:1]})
    obs, qpos = [o[0]], [info["qpos"][0]]
    for z in zs:
        o, _, _, _, inf = env.step(np.asarray(bfm.act(o, z[None]), dtype=np.float32))
        if inf["diverged"][0]:
            env.close()
            return np.stack(obs), np.stack(qpos), True
        obs.append(inf["final_obs"][0])
        qpos.append(inf["final_qpos"][0])
    env.close()
    return np.stack(obs), np.stack(qpos), False


def stays_up(qpos: np.ndarray, clip, diverged: bool) -> tuple[bool, int | None]:
    """Up to the clip's end, and the first frame the body lay where the reference did not."""
    n = len(qpos)
    fell = (qpos[:, 2] < FALLEN_HEIGHT) & (clip.qpos[:n, 2] >= FALLEN_HEIGHT)
    first = int(np.argmax(fell)) if fell.any() else None
    return (not diverged and first is None and n == clip.n_frames), first


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips", nargs="+", type=Path)
    ap.add_argument("--model", default="pretrained")
    ap.add_argument("--candidates", type=int, default=32)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--window", type=int, default=8)
    ap.add_argument("--horizon", type=int, default=24)
    ap.add_argument("--sigma", type=float, default=0.6)
    ap.add_argument("--decay", type=float, default=0.6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--position-weight", type=float, default=0.0)
    ap.add_argument("--leads", type=int, nargs="*", default=[])
    ap.add_argument("--lookaheads", type=int, nargs="*", default=[])
    ap.add_argument("--cold", action="store_true", help="no warm start from the last window's shift")
    ap.add_argument("--threads", type=int, default=1, help="MuJoCo threads of the batched envs")
    ap.add_argument("--max-frames", type=int, default=0, help="cut each clip to this many frames (0: whole)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    bfm = BFM.load(args.model)
    settings = Receding(candidates=args.candidates, rounds=args.rounds, window=args.window, horizon=args.horizon,
                        sigma=args.sigma, decay=args.decay, seed=args.seed,
                        warm=not args.cold, position_weight=args.position_weight, leads=tuple(args.leads),
                        lookaheads=tuple(args.lookaheads))
    rows = []
    for path in args.clips:
        clip = load_motion(path)
        if args.max_frames and clip.n_frames > args.max_frames:
            n = args.max_frames
            clip = dataclasses.replace(clip, qpos=clip.qpos[:n], qvel=clip.qvel[:n], obs=clip.obs[:n])
        zs = bfm.prompt.track(clip)
        z_obs, z_qpos, z_div = zero_shot(bfm, clip, zs)
        load0 = os.getloadavg()[0]
        t = time.perf_counter()
        res = bfm.prompt.track_refined(clip, settings, num_threads=args.threads)
        wall = time.perf_counter() - t
        floor = hold_first_pose(clip)
        row = {"clip": clip.name, "frames": clip.n_frames,
               "mpjpe_floor": mpjpe(floor, clip.obs), "emd_floor": emd(floor, clip.obs),
               "mpjpe_zero": mpjpe(z_obs, clip.obs[: len(z_obs)]), "emd_zero": emd(z_obs, clip.obs),
               "mpjpe_refined": mpjpe(res.obs, clip.obs[: len(res.obs)]), "emd_refined": emd(res.obs, clip.obs),
               "up_zero": stays_up(z_qpos, clip, z_div)[0], "up_refined": stays_up(res.qpos, clip,
                                                                                   res.diverged_at is not None)[0],
               "fell_zero": stays_up(z_qpos, clip, z_div)[1], "fell_refined": stays_up(res.qpos, clip,
                                                                                       res.diverged_at is not None)[1],
               "plan_cost0": float(res.plan_cost0.mean()), "plan_cost": float(res.plan_cost.mean()),
               "s_per_s": res.cost, "cpu_s_per_s": res.cpu_cost, "cpu": res.cpu_seconds, "wall": wall, "load": [load0, os.getloadavg()[0]]}
        rows.append(row)
        print(f"{row['clip']:>16} {row['frames']:5d}  mpjpe floor {row['mpjpe_floor']:.3f} zero "
              f"{row['mpjpe_zero']:.3f} ref {row['mpjpe_refined']:.3f} | emd floor {row['emd_floor']:.2f} zero "
              f"{row['emd_zero']:.2f} ref {row['emd_refined']:.2f} | up {row['up_zero']:d}/{row['up_refined']:d} "
              f"| {row['s_per_s']:.1f} s/s wall, {row['cpu_s_per_s']:.1f} cpu, load {row['load'][0]:.1f}-{row['load'][1]:.1f}", flush=True)
    keys = ("mpjpe_zero", "mpjpe_refined", "emd_zero", "emd_refined")
    ratio = {k: float(np.mean([r[k] / r[k.split("_")[0] + "_floor"] for r in rows])) for k in keys}
    summary = {"settings": vars(settings), "model": args.model, "ratio_to_floor_mean": ratio,
               "up_zero": float(np.mean([r["up_zero"] for r in rows])),
               "up_refined": float(np.mean([r["up_refined"] for r in rows])),
               "s_per_s_overall": float(sum(r["wall"] for r in rows) / sum((r["frames"] - 1) / 30 for r in rows)),
               "cpu_s_per_s_overall": float(sum(r["cpu"] for r in rows) / sum((r["frames"] - 1) / 30 for r in rows))}
    print(json.dumps(summary, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"summary": summary, "clips": rows}, indent=1))


if __name__ == "__main__":
    main()
