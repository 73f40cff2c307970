"""Where the refined tracker's EMD comes from: d_smpl split into root height, body positions and body orientations
(per body), for the refined body and the first-pose floor, on a few clips (lab/log.md 71)."""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
import torch

from fbcpr.eval.runner import hold_first_pose
from fbcpr.inference.bfm import BFM
from fbcpr.inference.prompt import load_motion
from fbcpr.inference.track_refine import Receding, refine_track
from fbcpr.metrics import emd, mpjpe
from humanoid_env.observation import BODY_POS, BODY_ROT, ROOT_HEIGHT


def parts(a: np.ndarray, r: np.ndarray) -> dict[str, float]:
    """Mean over steps of each part's squared distance (they add up to d_smpl squared)."""
    sq = (a[:, :214] - r[:, :214]) ** 2
    rot = sq[:, BODY_ROT].reshape(len(a), 24, 6).sum(-1)
    return {"height": float(sq[:, ROOT_HEIGHT].sum(-1).mean()), "pos": float(sq[:, BODY_POS].sum(-1).mean()),
            "rot": float(rot.sum(-1).mean()), "rot_by_body": rot.mean(0).round(3).tolist(),
            "d_smpl": float(np.sqrt(sq.sum(-1)).mean())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("clips", nargs="+", type=Path)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--seed", type=int, default=7101)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    torch.set_num_threads(1)
    bfm = BFM.load("pretrained")
    rows = []
    for path in args.clips:
        clip = load_motion(path)
        n = min(args.frames, clip.n_frames)
        clip = dataclasses.replace(clip, qpos=clip.qpos[:n], qvel=clip.qvel[:n], obs=clip.obs[:n])
        zs = bfm.prompt.track(clip)
        res = refine_track(bfm, clip.obs, (clip.qpos[0], clip.qvel[0]), zs, Receding(seed=args.seed), num_threads=1)
        floor = hold_first_pose(clip)
        m = len(res.obs)
        row = {"clip": clip.name, "emd_ref": emd(res.obs, clip.obs), "emd_floor": emd(floor, clip.obs),
               "mpjpe_ref": mpjpe(res.obs, clip.obs[:m]), "mpjpe_floor": mpjpe(floor, clip.obs),
               "refined": parts(res.obs, clip.obs[:m]), "floor": parts(floor, clip.obs),
               "cpu_s_per_s": res.cpu_cost}
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k not in ("refined", "floor")}), flush=True)
        for who in ("refined", "floor"):
            p = row[who]
            print(f"  {who:8s} d_smpl {p['d_smpl']:.3f} height {p['height']:.4f} pos {p['pos']:.3f} "
                  f"rot {p['rot']:.3f} by body {p['rot_by_body']}", flush=True)
        if args.out:
            np.savez(args.out.with_suffix(f".{clip.name}.npz"), obs=res.obs, ref=clip.obs)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
