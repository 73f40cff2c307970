"""Getting up with feedback around planned rises: a funnel library of time-varying LQR laws, then a stand policy.

    python lab/experiments/funnel_rise.py build data/demos/getup-all --out runs/funnel
    python lab/experiments/funnel_rise.py mark runs/funnel pretrained
    python lab/experiments/funnel_rise.py eval runs/funnel pretrained --episodes 64 --seed 0

`build`: each planned rise (`lab/experiments/getup_planner.py --save`) is replayed, extended by the planner settling
into the rest stand (`--settle` steps: the planner's own stand waves its arms), and the feedback gains along it
are computed (`lqr.stabilise`, ~0.3 s a step); rises that do not end up (pelvis above 0.8 m over the
last second) are left out. Files already in the folder are kept, so a stopped build resumes.
`mark`: from every `--stride`-th state of each trajectory the agent acts alone under the stand prompt for 5 s;
the states it holds from (it held from this one and the next checked one) become the trajectory's handoff states.
`eval`: fall starts, the same draws as `fbcpr.eval.upright.fall_starts_got_up` (so its seed's agent row is
the targets' measure): the agent alone under the stand prompt; the library acting until its nearest state is a
handoff state, where the agent takes over; and the same with the agent keeping the bodies it has while their pelvis
stays above `--release` m. The share that is up over the last second is printed for each.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from rich.progress import Progress

from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import EPISODE_STEPS
from fbcpr.eval.upright import STAND_PROMPT, STANDING, action_mapping, got_up, pelvis_heights
from humanoid_env.env import HumanoidEnv
from humanoid_env.errors import EnvError
from humanoid_env.inits import FallInit, FixedStates
from lqr import HOLD_RELEASE, FunnelLibrary, StabilisedTrajectory, rest_stand, stabilise
from humanoid_env.model import CONTROL_HZ
from planner import PlannerConfig, TrackingPlanner
from humanoid_env.vector import VectorHumanoidEnv
from motions.demonstrations import DemonstrationError, load_demonstrations

#: What the planner weighs to settle: the pose and stillness, more than its default tracking does.
SETTLE_PLANNER = ("w_pose=10", "w_joint_speed=0.01", "w_root_speed=1")
#: Seconds the agent alone must hold from a state for it to count as a handoff state.
HOLD_S = 5


def build(args: argparse.Namespace) -> None:
    """Replay, settle and stabilise each demonstration into the library folder (module docstring)."""
    demos = load_demonstrations(args.demos)
    args.out.mkdir(parents=True, exist_ok=True)
    env = HumanoidEnv(max_episode_steps=10**9)
    rest_q, _, _ = rest_stand(env)
    cfg = PlannerConfig(threads=args.threads).with_overrides([*SETTLE_PLANNER, *args.planner])
    with Progress() as bar:
        for demo in demos:
            out = args.out / f"{demo.clip.name}.npz"
            if out.exists():
                continue
            start = time.perf_counter()
            env.reset(options={"qpos": demo.clip.qpos[0], "qvel": demo.clip.qvel[0]})
            for a in demo.actions:
                env.step(a)
            reference = np.repeat(rest_q[None], 2, 0)
            reference[:, 0:2] = env.data.qpos[0:2]
            settle = TrackingPlanner(reference, cfg).run(env.data.qpos.copy(), env.data.qvel.copy(), args.settle,
                                                         start_frame=1.0)
            actions = np.concatenate([demo.actions, settle.actions])
            if not got_up(np.concatenate([demo.clip.qpos[:, 2], settle.qpos[1:, 2]])[:, None])[0]:
                print(f"{demo.clip.name}: left out, does not end up (end pelvis {settle.qpos[-1, 2]:.2f} m)",
                      flush=True)
                continue
            task = bar.add_task(demo.clip.name[:40], total=len(actions))
            traj = stabilise(demo.clip.qpos[0], demo.clip.qvel[0], actions,
                             progress=lambda t: bar.update(task, completed=t + 1))
            bar.remove_task(task)
            traj.save(out)
            print(f"{demo.clip.name}: {len(actions)} steps, end pelvis {traj.qpos[-1, 2]:.2f} m "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)


def mark(args: argparse.Namespace) -> None:
    """Write each trajectory's handoff states: where the agent alone holds the stand (module docstring)."""
    agent = make_agent(args.agent)
    z = np.asarray(agent.reward_z(STAND_PROMPT), dtype=np.float32)
    for path in sorted(args.library.glob("*.npz")):
        traj = StabilisedTrajectory.load(path)
        T = len(traj.actions)
        checked = np.arange(0, T, args.stride)
        up = traj.qpos[checked, 2] > STANDING
        held = np.zeros(len(checked), bool)
        if up.any():  # the agent alone from those states, as the stand prompt's upright measure runs it
            starts = FixedStates(traj.qpos[checked[up]], traj.qvel[checked[up]])
            held[up] = got_up(pelvis_heights(agent, starts, int(up.sum()), HOLD_S * CONTROL_HZ, 0, z))
        # a state hands over when the agent held from its checked state and from the next one
        both = held & np.append(held[1:], held[-1])
        traj.handoff = np.repeat(both, args.stride)[:T]
        traj.save(path)
        print(f"{path.name}: held from {held.sum()} of {len(checked)} checked states, first handoff at step "
              f"{int(np.argmax(traj.handoff)) if traj.handoff.any() else '-'} of {T}", flush=True)


def evaluate(args: argparse.Namespace) -> None:
    """The agent alone and the library before it, from the same fall starts (module docstring)."""
    library = FunnelLibrary.load(args.library)
    agent = make_agent(args.agent)
    z = np.asarray(agent.reward_z(STAND_PROMPT), dtype=np.float32)
    print(f"{len(library.trajectories)} trajectories, {len(library.handoff)} states "
          f"({library.handoff.mean():.0%} handoff); {args.episodes} fall starts of seed {args.seed}")
    results = {}
    for name, use_library, hold in (("agent alone", False, False), ("library, then agent", True, False),
                                    ("... agent keeps bodies", True, True)):
        env = VectorHumanoidEnv(args.episodes, init=FallInit(), max_episode_steps=args.steps + 1,
                                action_mapping=action_mapping(agent))
        try:
            obs, info = env.reset(seed=args.seed + 1)
            zs = np.broadcast_to(z, (args.episodes, len(z)))
            heights, lqr_steps = np.empty((args.steps, args.episodes)), np.zeros(args.episodes, int)
            handed = np.zeros(args.episodes, bool)
            start = time.perf_counter()
            for t in range(args.steps):
                actions = np.asarray(agent.act(obs, zs), dtype=np.float64)
                if use_library:
                    feedback, handed = library.act(info["qpos"], info["qvel"], handed if hold else None,
                                                   args.release)
                    actions[~handed] = feedback[~handed]
                    lqr_steps += ~handed
                obs, _, _, _, info = env.step(actions)
                heights[t] = obs[:, 0]
        finally:
            env.close()
        results[name] = up = got_up(heights)
        extra = f", library acting {lqr_steps.mean() / args.steps:.0%} of steps" if use_library else ""
        print(f"{name:22s} up {up.sum():3d} of {args.episodes} ({up.mean():.2f}){extra} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)
    alone = results["agent alone"]
    print("up with the library, not alone: " + ", ".join(
        f"{name.strip('. ')} {(up & ~alone).sum()}" for name, up in results.items() if name != "agent alone"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="stabilised trajectories from planned rises")
    b.add_argument("demos", help="a folder of demonstrations (lab/experiments/getup_planner.py --save)")
    b.add_argument("--out", type=Path, required=True, help="the library folder (git-ignored runs/ fits)")
    b.add_argument("--settle", type=int, default=90, help="planner steps that settle into the rest stand")
    b.add_argument("--threads", type=int, default=2)
    b.add_argument("--planner", nargs="+", default=[], metavar="NAME=VALUE", help="other settle planner settings")
    m = sub.add_parser("mark", help="where the agent's stand takes over")
    m.add_argument("library", type=Path)
    m.add_argument("agent", help="a checkpoint dir, run dir or 'pretrained'")
    m.add_argument("--stride", type=int, default=10, help="check every STRIDE-th state")
    e = sub.add_parser("eval", help="fall starts: the agent alone, and the library then the agent")
    e.add_argument("library", type=Path)
    e.add_argument("agent", help="a checkpoint dir, run dir or 'pretrained'")
    e.add_argument("--episodes", type=int, default=64)
    e.add_argument("--steps", type=int, default=EPISODE_STEPS)
    e.add_argument("--seed", type=int, default=0, help="fall starts drawn as fall_starts_got_up draws seed's")
    e.add_argument("--release", type=float, default=HOLD_RELEASE,
                   help="pelvis height (m) below which a body the agent holds goes back to the library")
    args = ap.parse_args()
    for name in ("settle", "threads", "stride", "episodes", "steps"):
        if getattr(args, name, 1) < 1:
            ap.error(f"--{name} must be >= 1")
    try:
        {"build": build, "mark": mark, "eval": evaluate}[args.command](args)
    except (EnvError, DemonstrationError) as err:
        ap.error(str(err))


if __name__ == "__main__":
    main()
