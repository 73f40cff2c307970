"""Zero-shot tracking under other prompt-time choices (lab/log.md 71): the lookahead length L of the tracking z
(z_t = proj(sum of B over the next L states)), a lead (the z of step t + k played at t, for a body that lags), and
a discount within the lookahead (weights gamma^j), all rolled out as one batch of envs per clip from its first
state; MPJPE and EMD against the first-pose floor. For training takes only when choosing; held-out once.

    python lab/experiments/track_prompt_sweep.py data/clips/tracking/train/*.npz --max-frames 150 --out runs/sweep.json
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import torch

from fbcpr.eval.runner import hold_first_pose
from fbcpr.inference.bfm import BFM
from fbcpr.inference.prompt import load_motion
from fbcpr.inference.refine import project
from fbcpr.metrics import emd, mpjpe
from humanoid_env.env import FALLEN_HEIGHT
from humanoid_env.vector import VectorHumanoidEnv


def prompt_zs(b: np.ndarray, length: int, lead: int, gamma: float) -> np.ndarray:
    """(T-1, d): z_t = proj(sum_{j=1..L} gamma^(j-1) B(s_{t+lead+j})), the window clipped at the clip's end."""
    steps = len(b) - 1
    idx = np.arange(steps)[:, None] + lead + 1 + np.arange(length)[None]
    w = np.where(idx < len(b), gamma ** np.arange(length)[None], 0.0)
    w[:, 0] = np.where(w.sum(1) == 0, 1.0, w[:, 0])  # past the end: the last state alone
    return project((w[..., None] * b[np.minimum(idx, len(b) - 1)]).sum(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clips", nargs="+", type=Path)
    ap.add_argument("--model", default="pretrained")
    ap.add_argument("--lengths", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    ap.add_argument("--leads", type=int, nargs="+", default=[0, 2, 4])
    ap.add_argument("--gammas", type=float, nargs="+", default=[1.0])
    ap.add_argument("--max-frames", type=int, default=150)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    bfm = BFM.load(args.model)
    configs = list(itertools.product(args.lengths, args.leads, args.gammas))
    rows = []
    for path in args.clips:
        clip = load_motion(path)
        n = min(args.max_frames, clip.n_frames)
        clip = dataclasses.replace(clip, qpos=clip.qpos[:n], qvel=clip.qvel[:n], obs=clip.obs[:n])
        b = bfm.backward(clip.obs).astype(np.float64)
        zs = np.stack([prompt_zs(b, *c) for c in configs]).astype(np.float32)  # (C, T-1, d)
        env = VectorHumanoidEnv(len(configs), max_episode_steps=n, num_threads=1, action_mapping=bfm.action_mapping)
        o, _ = env.reset(options={"qpos": np.repeat(clip.qpos[:1], len(configs), 0),
                                  "qvel": np.repeat(clip.qvel[:1], len(configs), 0)})
        traj, alive = [o], np.ones(len(configs), bool)
        for t in range(n - 1):
            o, _, _, _, inf = env.step(np.asarray(bfm.act(o, zs[:, t]), dtype=np.float32))
            alive &= ~inf["diverged"]
            traj.append(inf["final_obs"])
        env.close()
        traj_a = np.stack(traj, 1)  # (C, n, obs)
        floor = hold_first_pose(clip)
        mf, ef = mpjpe(floor, clip.obs), emd(floor, clip.obs)
        for c, tr, ok in zip(configs, traj_a, alive):
            fell = bool(((tr[:, 0] < FALLEN_HEIGHT) & (clip.obs[:, 0] >= FALLEN_HEIGHT)).any()) or not ok
            rows.append({"clip": clip.name, "length": c[0], "lead": c[1], "gamma": c[2],
                         "mpjpe": mpjpe(tr, clip.obs) / mf, "emd": emd(tr, clip.obs) / ef, "fell": fell})
        print(clip.name, flush=True)
    table = {}
    for c in configs:
        sel = [r for r in rows if (r["length"], r["lead"], r["gamma"]) == c]
        table[str(c)] = {"mpjpe": float(np.mean([r["mpjpe"] for r in sel])),
                         "emd": float(np.mean([r["emd"] for r in sel])), "falls": int(sum(r["fell"] for r in sel))}
        print(f"L {c[0]:3d} lead {c[1]:2d} gamma {c[2]:.2f}: MPJPE {table[str(c)]['mpjpe']:.3f}x "
              f"EMD {table[str(c)]['emd']:.3f}x falls {table[str(c)]['falls']}", flush=True)
    if args.out:
        args.out.write_text(json.dumps({"table": table, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
