"""Under a demonstration's own z's, where does the model's pelvis go? Saves each clip's whole-clip z and its last
tracking window's z (for `z_search.py --judge`) and prints the pelvis height each second from the default standing
start under each (lab/log.md 56: did training on the planner's crouches teach the crouch?).

    python lab/experiments/demo_latents.py runs/s56/cand-crouch data/demos/crouch --out runs/s56/demoz_cand
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fbcpr import BFM
from fbcpr.eval.upright import pelvis_heights
from humanoid_env.inits import DefaultInit
from humanoid_env.model import CONTROL_HZ
from motions.library import MotionLibrary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("demos", type=Path, help="a folder of clips or demonstrations")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    args.out.mkdir(parents=True, exist_ok=True)
    for clip in MotionLibrary.load(args.demos).clips:
        zs = {f"imitate_{clip.name}": bfm.prompt.imitate(clip), f"track_end_{clip.name}": bfm.prompt.track(clip)[-1]}
        for name, z in zs.items():
            np.save(args.out / f"{name}.npy", np.asarray(z, np.float32))
            h = pelvis_heights(bfm, DefaultInit(0.0, 0.0), 1, args.steps, seed=0, prompt=z,
                               num_threads=1)[CONTROL_HZ - 1::CONTROL_HZ, 0]
            print(f"{name}: pelvis each second {np.round(h, 2).tolist()}", flush=True)


if __name__ == "__main__":
    main()
