"""Where along a getting-up clip a model takes over: starts on the clip's frames, under the stand prompt.

    python lab/experiments/rise_from_clip.py pretrained --clip data/clips/mixed/getup_facedown.npz

Fall starts test a whole rise, and no model passes them (lab/log.md section 21). This asks how much of the
rise is missing: episodes begin on frames near each fraction of the clip (the `--episodes` frames centred there).
Each then runs 10 s under the stand prompt. Per fraction it prints how many stayed up: the pelvis above 0.8 m over
the last second, as for fall starts. It also prints the median highest pelvis. The zero action runs first, as the
floor: it stands from the frames that are already up.
"""
from __future__ import annotations

import argparse

import numpy as np

from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import EPISODE_STEPS
from fbcpr.eval.upright import got_up, pelvis_heights
from humanoid_env.inits import FixedStates
from motions.clip import load_clip


def frames_near(fraction: float, n_frames: int, count: int) -> np.ndarray:
    """`count` consecutive frame indices centred on `fraction` of the clip, kept inside it."""
    centre = round(fraction * (n_frames - 1))
    start = min(max(0, centre - count // 2), max(0, n_frames - count))
    return np.arange(start, start + count) % n_frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agents", nargs="*", help="checkpoint dirs, run dirs or 'pretrained' (the zero action always runs)")
    ap.add_argument("--clip", required=True, help="a clip .npz of getting up (fbcpr motions import)")
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.0, 0.2, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
    ap.add_argument("--episodes", type=int, default=8, help="starts per fraction")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    if any(not 0.0 <= f <= 1.0 for f in args.fractions):
        ap.error(f"--fractions: each must be in [0, 1], got {args.fractions}")
    clip = load_clip(args.clip)
    starts = [frames_near(f, clip.n_frames, args.episodes) for f in args.fractions]
    print(f"{clip.name}: {clip.n_frames} frames; up = pelvis above 0.8 m over the last second, of {args.episodes}; "
          "(median highest pelvis, m)")
    print(f"{'agent':28s} " + " ".join(f"{f:>12.2f}" for f in args.fractions))
    print(f"{'clip pelvis there (m)':28s} " + " ".join(f"{clip.qpos[i, 2].mean():12.2f}" for i in starts))
    for spec in ["zero", *args.agents]:
        agent = make_agent(spec, seed=args.seed)
        cells = []
        for index in starts:
            init = FixedStates(clip.qpos[index], clip.qvel[index])
            h = pelvis_heights(agent, init, args.episodes, EPISODE_STEPS, args.seed, num_threads=args.threads)
            cells.append(f"{got_up(h).sum():>3d} ({np.median(h.max(0)):.2f})")
        print(f"{spec:28s} " + " ".join(f"{c:>12s}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
