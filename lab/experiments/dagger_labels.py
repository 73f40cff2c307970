"""The planner as DAgger's expert: a policy acts from the demonstrations' first states, the planner labels its states.

    python lab/experiments/dagger_labels.py runs/demostart-s0/checkpoints/step_0000720384 --demos data/demos/getup-all \
        --count 4 --steps 60 --out data/demos/labels-r1

A close clone of the planner's rises leaves them within a second (lab/log.md section 34): it is trained on
the planner's states only. DAgger labels the learner's own states instead. Here the policy acts (under the stand
prompt) from each demonstration's first state, and a planner tracking that demonstration replans at every state
the policy reaches and records its own first action there. It prints, per demonstration, how far the policy's
actions lie from those labels (mean squared error per component) and where the pelvis ended, and `--out` saves
each rollout as a demonstration whose actions are the policy's and whose labels are the planner's. A label costs
one plan: about 1.1 s of both cores with the default 32 samples (2.4 s on one beside training). `--noise-seeds`
measures how much of a label is the planner's noise; `--reference` has one clip tracked from every start
(lab/log.md section 36: otherwise a label depends on which demonstration a rollout started from).
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from fbcpr.inference.agents import make_agent
from fbcpr.eval.upright import STAND_PROMPT, action_mapping
from humanoid_env.errors import EnvError
from planner import PlannedMotion, PlannerConfig, TrackingPlanner
from motions.clip import Clip, ClipFormatError, load_clip
from motions.demonstrations import Demonstration, DemonstrationError, load_demonstrations, save_demonstration


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("agent", help="a checkpoint dir, run dir or 'pretrained' (the policy that acts)")
    ap.add_argument("--demos", required=True, help="a folder of demonstrations (lab/experiments/getup_planner.py --save)")
    ap.add_argument("--reference", type=Path, help="a clip .npz for the planner to track from every start, instead of "
                    "each demonstration's own motion (so that a label depends on the state, not on the start)")
    ap.add_argument("--count", type=int, default=4, help="label rollouts from the first COUNT demonstrations")
    ap.add_argument("--steps", type=int, default=60, help="control steps per rollout (30 per second)")
    ap.add_argument("--samples", type=int, default=PlannerConfig.samples)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--planner", nargs="+", default=[], metavar="NAME=VALUE",
                    help="other PlannerConfig fields, e.g. warm_start=0.9 chains=4 (see PlannerConfig)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-seeds", type=int, nargs="+", default=[], metavar="SEED",
                    help="label each rollout again with these planner seeds (the policy acts the same) and print how "
                         "far their labels lie from --seed's: a label's noise, over each third of the rollout")
    ap.add_argument("--out", type=Path, help="folder for the labelled rollouts (git-ignored data/ fits); its name "
                    "ends theirs, so that the rounds of DAgger go in one folder")
    args = ap.parse_args()
    if args.count < 1 or args.steps < 1:
        ap.error(f"--count and --steps must be >= 1, got {args.count} and {args.steps}")
    try:
        demos = load_demonstrations(args.demos)[: args.count]
    except DemonstrationError as err:
        raise SystemExit(str(err)) from None
    try:
        reference = None if args.reference is None else load_clip(args.reference).qpos
    except ClipFormatError as err:
        raise SystemExit(str(err)) from None
    agent = make_agent(args.agent, seed=args.seed)
    mapping = action_mapping(agent)
    if mapping != demos[0].action_mapping:
        raise SystemExit(f"{args.agent} acts under the {mapping!r} action mapping, the demonstrations under "
                         f"{demos[0].action_mapping!r}")
    z = agent.reward_z(STAND_PROMPT)[None]
    try:
        cfg = PlannerConfig(samples=args.samples, threads=args.threads, seed=args.seed).with_overrides(args.planner)
    except EnvError as err:
        ap.error(str(err))
    print(f"{args.agent} acting from the first states of {len(demos)} demonstrations, {args.steps} steps each; the "
          f"planner ({cfg.samples} samples) labels every state")
    noise_column = " | label noise, mse by thirds" if args.noise_seeds else ""
    print(f"| demonstration | policy vs label, mse | pelvis at the end (m){noise_column} | seconds |\n"
          f"|---|---:|---:|{'---:|' * bool(args.noise_seeds)}---:|")
    gaps, noises = [], []
    for d in demos:
        start = time.perf_counter()

        def label(seed: int) -> PlannedMotion:
            planner = TrackingPlanner(d.clip.qpos if reference is None else reference, replace(cfg, seed=seed),
                                      action_mapping=mapping)
            return planner.run(d.clip.qpos[0], d.clip.qvel[0], args.steps,
                               policy=lambda obs: agent.act(obs[None], z)[0])

        m = label(args.seed)
        gap = float(np.square(m.actions - m.labels).mean())
        gaps.append(gap)
        noise = ""
        if args.noise_seeds:
            per_step = np.mean([label_noise(m, label(seed)) for seed in args.noise_seeds], 0)
            noises.append([part.mean() for part in np.array_split(per_step, 3)])
            noise = " | " + " / ".join(f"{x:.4f}" for x in noises[-1])
        print(f"| {d.clip.name} | {gap:.4f} | {m.qpos[-1, 2]:.2f}{noise} | {time.perf_counter() - start:.0f} |",
              flush=True)
        if args.out:
            clip = Clip(qpos=m.qpos, qvel=m.qvel, obs=m.obs.astype(np.float32), name=f"{d.clip.name}_{args.out.name}",
                        source=f"{args.agent} from the first state of {d.clip.name}, labelled by the planner "
                               f"tracking {args.reference or d.clip.name}",
                        license=d.clip.license)
            save_demonstration(Demonstration(clip, m.actions, mapping, m.labels), args.out / f"{clip.name}.npz")
    print(f"mean policy vs label mse over {len(gaps)} rollouts: {np.mean(gaps):.4f}")
    if noises:
        print(f"mean label noise (mse to seed {args.seed}'s labels) over {len(noises)} rollouts, by thirds: "
              + " / ".join(f"{x:.4f}" for x in np.mean(noises, 0)))


def label_noise(first: PlannedMotion, other: PlannedMotion) -> np.ndarray:
    """(T,) squared distance per step between two planner seeds' labels of one rollout; the same states are
    required, so that the difference is the planner's alone."""
    if not np.allclose(first.qpos, other.qpos, atol=1e-6):
        raise SystemExit("the policy acted differently under two planner seeds: its label noise cannot be measured")
    return np.square(first.labels - other.labels).mean(1)


if __name__ == "__main__":
    main()
