"""How exactly a rise must be followed: the planner's motions replayed with noise, and policies from their starts.

    python lab/experiments/demo_drift.py data/demos/getup-all --noise 0 0.02 0.05 0.08 --agents runs/demostart-s0

A policy that clones the demonstrations closely (an RMS error of 0.08 per joint on their states) still did not
rise from their own first states (lab/log.md section 34). This asks whether that error alone undoes a rise:
every demonstration starts from its first state and is replayed open loop with its own actions plus N(0, sigma²)
noise per component (clipped to [-1, 1]), and each named agent runs from the same states under the stand prompt.
Per row it prints how many ended up (the pelvis above 0.8 m over the last second, as for fall starts) and the
median seconds before the pelvis first strays more than 0.15 m from the demonstration's.
"""
from __future__ import annotations

import argparse

import numpy as np

from fbcpr.inference.agents import make_agent
from fbcpr.eval.upright import CONTROL_HZ, got_up, pelvis_heights
from humanoid_env.inits import FixedStates
from humanoid_env.vector import VectorHumanoidEnv
from motions.demonstrations import Demonstration, DemonstrationError, load_demonstrations

#: The pelvis this far (m) from the demonstration's counts as off its track.
OFF_TRACK = 0.15


def first_states(demos: list[Demonstration]) -> FixedStates:
    """Initial states: each demonstration's first frame, in order (env i starts demonstration i)."""
    return FixedStates(np.stack([d.clip.qpos[0] for d in demos]), np.stack([d.clip.qvel[0] for d in demos]))


def noisy_replay(demos: list[Demonstration], sigma: float, steps: int, seed: int = 0, threads: int = 1) -> np.ndarray:
    """Pelvis heights (steps, demos) after each step of each demonstration's own actions plus N(0, sigma²) noise,
    open loop from its first state (agents run through `fbcpr.eval.upright.pelvis_heights`, rows alike)."""
    actions = np.stack([d.actions[:steps] for d in demos], axis=1)  # (steps, demos, A)
    noise = np.random.default_rng(seed).normal(0.0, sigma, actions.shape) if sigma else 0.0
    actions = np.clip(actions + noise, -1.0, 1.0).astype(np.float32)
    env = VectorHumanoidEnv(len(demos), init=first_states(demos), max_episode_steps=steps + 1,
                            action_mapping=demos[0].action_mapping, num_threads=threads)
    try:
        env.reset(seed=0)
        return np.stack([env.step(a)[0][:, 0] for a in actions])
    finally:
        env.close()


def seconds_on_track(heights: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per demonstration, seconds before the pelvis first strays more than OFF_TRACK from the reference."""
    off = np.abs(heights - reference) > OFF_TRACK
    return np.where(off.any(0), off.argmax(0), len(heights)) / CONTROL_HZ


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("demos", help="a folder of demonstrations (lab/experiments/getup_planner.py --save)")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.02, 0.05, 0.08], help="sigma of action noise")
    ap.add_argument("--agents", nargs="*", default=[], help="checkpoint dirs, run dirs or 'pretrained'")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    if any(not 0.0 <= s <= 2.0 for s in args.noise):
        ap.error(f"--noise: each sigma must be in [0, 2], got {args.noise}")
    try:
        demos = load_demonstrations(args.demos)
    except DemonstrationError as err:
        raise SystemExit(str(err)) from None
    steps = min(len(d.actions) for d in demos)
    reference = np.stack([d.clip.qpos[1: steps + 1, 2] for d in demos], axis=1)  # after each step
    print(f"{len(demos)} demonstrations of {args.demos}, {steps} steps from each one's first state; up of "
          f"{len(demos)}, and median seconds with the pelvis within {OFF_TRACK} m of the demonstration's")
    rows = [(f"own actions, noise {s:g}", noisy_replay(demos, s, steps, args.seed, args.threads)) for s in args.noise]
    for spec in ["zero", *args.agents]:
        heights = pelvis_heights(make_agent(spec, seed=args.seed), first_states(demos), len(demos), steps, args.seed,
                                 num_threads=args.threads)
        rows.append((spec, heights))
    print("| actions | up | on track (s) |\n|---|---:|---:|")
    for name, h in rows:
        print(f"| {name} | {got_up(h).sum()} | {np.median(seconds_on_track(h, reference)):.2f} |", flush=True)


if __name__ == "__main__":
    main()
