"""Can this body jump, or crouch and hold it? The sampling planner tracks a reference, judged by the behaviour check.

    python lab/experiments/skill_planner.py --skill crouch --pose crouch_medium --ramp 1 --save data/demos/crouch
    python lab/experiments/skill_planner.py --skill jump --seeds 0 1 --steps 75 \
        --planner samples=64 noise=0.2 iterations=2 elites=4 --save data/demos/jump

No prompt of the shipped model jumps or crouches (lab/log.md sections 54-56), and tracking DeepMimic's jump the
model peaks 0.04 m above standing. Before training at scale for them, this asks what section 32 asked of getting
up: does the physics allow it, with this env's PD gains and torque limits? `planner.TrackingPlanner` tracks

- jump: DeepMimic's jump clip from its first frame (standing), after `--hold` seconds of that frame, since the
  behaviour check reads a jump only after the first second;
- crouch: the default standing pose lowered into the named goal pose (`--pose`) over `--ramp` seconds, then held.

Each planned motion is judged by the family's own rule (`fbcpr.eval.behaviours`), next to the zero action from
the same start. `--save DIR` writes each motion that passes as a demonstration (the states and the actions that
made them), which training can take as transitions (`train.demonstrations`).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from planner import PlannerConfig, TrackingPlanner

from fbcpr.eval import behaviours as B
from humanoid_env.env import HumanoidEnv
from humanoid_env.inits import DefaultInit
from humanoid_env.model import CONTROL_HZ, NU
from humanoid_env.tasks.goals import goal_qpos
from motions.clip import Clip, load_clip
from motions.demonstrations import Demonstration, save_demonstration


def crouch_reference(pose: str, start: np.ndarray, frames: int, seconds: float = 1.0) -> np.ndarray:
    """`frames` qpos frames from `start` (76,) to the goal pose, linear over `seconds` (root quaternion
    renormalised), then held: past a reference's end the planner would blend back into the standing rest pose."""
    end = goal_qpos(pose).copy()
    end[:2] = start[:2]
    a = np.minimum(np.arange(frames) / (seconds * CONTROL_HZ), 1.0)[:, None]
    ref = start[None] * (1 - a) + end[None] * a
    ref[:, 3:7] /= np.linalg.norm(ref[:, 3:7], axis=1, keepdims=True)
    return ref


def judge(family: str, obs: np.ndarray) -> tuple[bool, dict[str, float]]:
    """The behaviour family's rule on one episode's observations (T, 358)."""
    fam = B.families([family])[0]
    assert fam.judge is not None
    ok, measures = fam.judge(B.Trace(obs[:, None]))
    return bool(ok[0]), {k: float(v[0]) for k, v in measures.items()}


def zero_action_obs(qpos: np.ndarray, qvel: np.ndarray, steps: int) -> np.ndarray:
    env = HumanoidEnv(max_episode_steps=steps + 1)
    obs, _ = env.reset(options={"qpos": qpos, "qvel": qvel})
    out = [obs]
    for _ in range(steps):
        out.append(env.step(np.zeros(NU))[0])
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skill", choices=["jump", "crouch"], required=True)
    ap.add_argument("--clip", default="data/clips/deepmimic/jump.npz", help="jump: the clip tracked")
    ap.add_argument("--pose", default="crouch_medium", help="crouch: the goal pose lowered into")
    ap.add_argument("--hold", type=float, default=1.0, help="jump: seconds on the clip's first frame first")
    ap.add_argument("--ramp", type=float, default=1.0, help="crouch: seconds from standing to the pose")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--steps", type=int, default=150, help="control steps per start (30 per second)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--planner", nargs="+", default=[], metavar="NAME=VALUE",
                    help="PlannerConfig fields, e.g. samples=64 horizon=30 (see PlannerConfig)")
    ap.add_argument("--save", type=Path, help="folder for the motions that pass, as demonstrations")
    args = ap.parse_args()
    if args.ramp <= 0:
        ap.error(f"--ramp must be > 0 seconds, got {args.ramp}")
    base = PlannerConfig(threads=args.threads).with_overrides(args.planner)
    if args.skill == "jump":
        clip = load_clip(args.clip)
        ref, name, q0, v0 = clip.qpos, clip.name, clip.qpos[0], np.zeros_like(clip.qvel[0])
        start_frame = -args.hold * CONTROL_HZ
        source, license_ = f"planner tracking {clip.name} ({clip.source})", clip.license
    else:
        q, v = DefaultInit(0.0, 0.0).sample(np.random.default_rng(0), 1)
        q0, v0 = q[0], v[0]
        ref = crouch_reference(args.pose, q0, args.steps + base.horizon + 1, args.ramp)
        name, start_frame = args.pose, 0.0
        source, license_ = f"planner lowering into the goal pose {args.pose}", "package goal pose"
    family = args.skill
    ok, m = judge(family, zero_action_obs(q0, v0, args.steps))
    print(f"{family} from {name}: {args.steps} steps; planner {base}\n  zero action: {'PASS' if ok else 'fail'} {m}",
          flush=True)
    passed = 0
    for seed in args.seeds:
        t0 = time.perf_counter()
        planner = TrackingPlanner(ref, replace(base, seed=seed))
        motion = planner.run(q0, v0, args.steps, start_frame=start_frame)
        ok, m = judge(family, motion.obs)
        passed += ok
        pelvis = motion.qpos[:, 2]
        print(f"  planner seed {seed}: {'PASS' if ok else 'fail'} {m}  pelvis min {pelvis.min():.2f} max "
              f"{pelvis.max():.2f} last {pelvis[-1]:.2f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
        if args.save and ok:
            out = f"{name}_planned_{family}_s{seed}" + (f"_ramp{args.ramp:g}" if family == "crouch" else "")
            planned = Clip(qpos=motion.qpos, qvel=motion.qvel, obs=motion.obs.astype(np.float32), name=out,
                           source=source, license=license_)
            save_demonstration(Demonstration(planned, motion.actions, planner.amap.mapping),
                               args.save / f"{out}.npz")
    print(f"{family}: {passed} of {len(args.seeds)} planned motions pass")


if __name__ == "__main__":
    main()
