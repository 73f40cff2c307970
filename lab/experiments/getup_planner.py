"""Can this body get up at all? A sampling planner that sees the simulator tracks a getting-up clip.

    python lab/experiments/getup_planner.py --clip data/clips/deepmimic/getup_facedown.npz --fractions 0 0.6 0.8 --seeds 0 1

No learnt policy has got up (lab/log.md sections 18-31), and two TD3 probes did not even rise from the clip's
crouch. This asks whether the physics allows it: `planner.TrackingPlanner` (predictive sampling over
the env's own MuJoCo model) tracks the clip from its frame at each fraction, then holds the rest pose, for
`--steps` control steps. Per start it prints whether the body is up (the pelvis above 0.8 m over the last second,
as for fall starts), the highest and last pelvis height and the seconds it took. The zero action from the same
start runs first, as the floor. `--fall-starts N` adds N of the env's fall starts (`FallInit`, seeded by the
first seed), each tracking the clip from its first frame. `--save DIR` writes each planned motion that ends up as a
demonstration (`motions.demonstrations`: the clip and the actions that made it, physically consistent by
construction), which training can take as transitions (`train.demonstrations`).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from fbcpr.eval.upright import got_up
from humanoid_env.env import HumanoidEnv
from humanoid_env.errors import EnvError
from humanoid_env.inits import FallInit
from humanoid_env.model import NU
from planner import PlannerConfig, TrackingPlanner
from motions.clip import Clip, load_clip
from motions.demonstrations import Demonstration, save_demonstration


def zero_action_heights(qpos: np.ndarray, qvel: np.ndarray, steps: int) -> np.ndarray:
    """Pelvis heights (steps + 1,) of the zero action (the rest pose's PD targets) from the state."""
    env = HumanoidEnv(max_episode_steps=steps + 1)
    env.reset(options={"qpos": qpos, "qvel": qvel})
    heights = [qpos[2]]
    for _ in range(steps):
        heights.append(env.step(np.zeros(NU))[4]["qpos"][2])
    return np.array(heights)


def is_up(heights: np.ndarray) -> bool:
    """Up as a fall start counts it: the pelvis above 0.8 m over the whole last second."""
    return bool(got_up(heights[:, None])[0])


def summary(heights: np.ndarray) -> str:
    return f"{'UP' if is_up(heights) else 'down':4s} max {heights.max():.2f} last {heights[-1]:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clip", required=True, help="a clip .npz of getting up (fbcpr motions import)")
    ap.add_argument("--fractions", type=float, nargs="*", default=[0.0, 0.6, 0.8],
                    help="clip fractions to start from (none: only the fall starts)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--fall-starts", type=int, default=0, help="fall starts, tracking the clip from its first frame")
    ap.add_argument("--steps", type=int, default=300, help="control steps per start (30 per second)")
    ap.add_argument("--samples", type=int, default=PlannerConfig.samples)
    ap.add_argument("--horizon", type=int, default=PlannerConfig.horizon)
    ap.add_argument("--noise", type=float, default=PlannerConfig.noise)
    ap.add_argument("--rate", type=float, default=PlannerConfig.rate)
    ap.add_argument("--balance", type=float, default=PlannerConfig.w_balance, help="weight of the balance term")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--planner", nargs="+", default=[], metavar="NAME=VALUE",
                    help="other PlannerConfig fields, e.g. warm_start=0.9 chains=4 (see PlannerConfig)")
    ap.add_argument("--save", type=Path, help="folder for the motions that end up, as demonstrations (git-ignored data/ fits)")
    args = ap.parse_args()
    if any(not 0.0 <= f <= 1.0 for f in args.fractions):
        ap.error(f"--fractions: each must be in [0, 1], got {args.fractions}")
    clip = load_clip(args.clip)
    try:
        base = PlannerConfig(samples=args.samples, horizon=args.horizon, noise=args.noise, rate=args.rate,
                             w_balance=args.balance, threads=args.threads).with_overrides(args.planner)
    except EnvError as err:
        ap.error(str(err))
    print(f"{clip.name}: {clip.n_frames} frames; {args.steps} steps per start; planner {base}")
    frames = [round(f * (clip.n_frames - 1)) for f in args.fractions]
    starts = [(f"fraction {f:.2f}", i, clip.qpos[i], clip.qvel[i]) for f, i in zip(args.fractions, frames)]
    if args.fall_starts:  # named with their FallInit seed: runs with other first seeds draw other falls
        fq, fv = FallInit().sample(np.random.default_rng(args.seeds[0]), args.fall_starts)
        starts += [(f"fall start {i} f{args.seeds[0]}", 0, fq[i], fv[i]) for i in range(args.fall_starts)]
    ups = {}
    for label, frame, q0, v0 in starts:
        print(f"{label} (frame {frame}, pelvis {q0[2]:.2f} m): zero action "
              f"{summary(zero_action_heights(q0, v0, args.steps))}", flush=True)
        for seed in args.seeds:
            start = time.perf_counter()
            planner = TrackingPlanner(clip.qpos, replace(base, seed=seed))
            motion = planner.run(q0, v0, args.steps, start_frame=frame)
            h = motion.qpos[:, 2]
            up = is_up(h)
            ups[label] = ups.get(label, 0) + int(up)
            print(f"  planner seed {seed}: {summary(h)}  ({time.perf_counter() - start:.0f} s)", flush=True)
            if args.save and up:
                name = f"{clip.name}_planned_{label.replace(' ', '_')}_s{seed}"
                planned = Clip(qpos=motion.qpos, qvel=motion.qvel, obs=motion.obs.astype(np.float32), name=name,
                               source=f"planner tracking {clip.name} ({clip.source})", license=clip.license)
                save_demonstration(Demonstration(planned, motion.actions, planner.amap.mapping), args.save / f"{name}.npz")
    print(f"up, of {len(args.seeds)} seeds: " + ", ".join(f"{k}: {n}" for k, n in ups.items()))


if __name__ == "__main__":
    main()
