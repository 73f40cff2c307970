"""Under a demonstration's own z's, where does the model's pelvis go? Saves each clip's whole-clip z and its last
tracking window's z (for `z_search.py --judge`) and prints the pelvis height each second from the default standing
start under each (lab/log.md 56: did training on the planner's crouches teach the crouch?). `--frames` adds the
tracking z's of chosen frames: a jump's last window is its landing, the z that could start one lies before takeoff
(lab/log.md 59). `--track` also tracks each clip step by step from its first state (`fbcpr track`) and reads the
jump rule off the rollout: is the skill there when the prompt changes every step?

    python lab/experiments/demo_latents.py runs/s56/cand-crouch data/demos/crouch --out runs/s56/demoz_cand
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from skill_planner import judge

from fbcpr import BFM
from fbcpr.cli.prompt_cmd import rollout
from fbcpr.eval.upright import pelvis_heights
from humanoid_env.inits import DefaultInit
from humanoid_env.model import CONTROL_HZ
from motions.library import MotionLibrary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("demos", type=Path, help="a folder of clips or demonstrations")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--frames", type=int, nargs="*", default=[], help="also the tracking z's of these frames")
    ap.add_argument("--track", action="store_true", help="also track each clip, judged by the jump rule")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if args.steps <= CONTROL_HZ:
        ap.error(f"--steps: give more than {CONTROL_HZ} (one second): the highest pelvis is read after it")
    bfm = BFM.load(args.checkpoint)
    args.out.mkdir(parents=True, exist_ok=True)
    for clip in MotionLibrary.load(args.demos).clips:
        track = bfm.prompt.track(clip)
        if any(not 0 <= t < len(track) for t in args.frames):
            raise SystemExit(f"--frames: {clip.name} has tracking z's for frames 0-{len(track) - 1}")
        zs = {f"imitate_{clip.name}": bfm.prompt.imitate(clip), f"track_end_{clip.name}": track[-1],
              **{f"track_{t:03d}_{clip.name}": track[t] for t in args.frames}}
        for name, z in zs.items():
            np.save(args.out / f"{name}.npy", np.asarray(z, np.float32))
            h = pelvis_heights(bfm, DefaultInit(0.0, 0.0), 1, args.steps, seed=0, prompt=z, num_threads=1)[:, 0]
            print(f"{name}: pelvis each second {np.round(h[CONTROL_HZ - 1::CONTROL_HZ], 2).tolist()}, "
                  f"highest {h[CONTROL_HZ:].max():.2f} after the first second", flush=True)
        if args.track:
            ep = rollout(bfm, track, start=(clip.qpos[0], clip.qvel[0]))
            ok, m = judge("jump", np.stack(ep.obs))
            print(f"tracked {clip.name}: apex {m['apex_gain']:+.2f} m over standing, "
                  f"{m['flight_steps']:.0f} flight steps, jump rule {'passed' if ok else 'failed'}", flush=True)


if __name__ == "__main__":
    main()
