"""Which checkpoints of a run get up under the stand prompt, and do they still stand? One line per checkpoint.

    python lab/experiments/getup_screen.py runs/cpu-getup-free/checkpoints/step_* --z-from pretrained --seed 230

A continuation with B frozen (`agent.freeze_backward`) infers every reward prompt through the loaded model's B, so
the stand z of the model it started from (`--z-from`) is the z its export would store: each checkpoint is judged
under that one z, from the behaviour check's fall starts (`fbcpr.eval.upright.got_up`: the pelvis above 0.8 m over
the last second) and from quiet standing starts (seconds until the pelvis first drops below 0.6 m), the zero
action first as the floor. `--demos DIR` also starts each demonstration's first state (lying) under its own
whole-clip z (ER_FB): is a rise in the policy under the prompt of the rise itself? Checkpoints kept every few
thousand updates are screened in minutes, so the one where a skill appears is found before later updates lose it
(lab/log.md 57-59).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from fbcpr import BFM
from fbcpr.eval.agents import ZeroAgent
from fbcpr.eval.upright import STAND_PROMPT, got_up, pelvis_heights, seconds_upright
from humanoid_env.inits import DefaultInit, FallInit, FixedStates
from humanoid_env.model import CONTROL_HZ
from motions.library import MotionLibrary


def screen(agent: object, z: np.ndarray | str, episodes: int, steps: int, seed: int) -> dict[str, float]:
    """Fall starts of `seed` got up (share), their mean pelvis over the last second, and the median seconds upright
    from quiet standing starts of the same seed; `z`: the stand z, or the prompt's name for a z-free floor."""
    fall = pelvis_heights(agent, FallInit(), episodes, steps, seed, z)
    stand = pelvis_heights(agent, DefaultInit(), episodes, steps, seed, z)
    return {"got_up": float(got_up(fall).mean()), "last_pelvis": float(fall[-CONTROL_HZ:].mean()),
            "stand_s": float(np.median(seconds_upright(stand)))}


def demo_rises(bfm: BFM, demos: MotionLibrary, steps: int) -> dict[str, float]:
    """Each demonstration from its first state under its own whole-clip z: the share that got up and the mean of
    the highest pelvis after the first second."""
    zs = np.stack([bfm.prompt.imitate(c) for c in demos.clips])
    starts = FixedStates(np.stack([c.qpos[0] for c in demos.clips]), np.stack([c.qvel[0] for c in demos.clips]))
    h = pelvis_heights(bfm, starts, len(demos), steps, 0, zs)
    return {"got_up": float(got_up(h).mean()), "highest": float(h[CONTROL_HZ:].max(0).mean())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", help="checkpoint folders (or run folders, or 'pretrained')")
    ap.add_argument("--z-from", default="pretrained", help="the model whose stand prompt every checkpoint is asked")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--demos", type=Path, help="also each of these demonstrations under its own whole-clip z")
    args = ap.parse_args()
    if args.episodes < 1 or args.steps <= CONTROL_HZ:
        ap.error(f"--episodes must be >= 1 and --steps > {CONTROL_HZ} (more than the last second, which the rule "
                 f"reads), got {args.episodes} and {args.steps}")
    torch.set_num_threads(args.threads)
    z = BFM.load(args.z_from).reward_z(STAND_PROMPT)
    demos = MotionLibrary.load(args.demos) if args.demos else None
    print(f"stand z of {args.z_from}; {args.episodes} fall and standing starts of seed {args.seed}, {args.steps} steps")
    for name in ["zero action", *args.checkpoints]:
        start = time.perf_counter()
        floor = name == "zero action"
        agent = ZeroAgent() if floor else BFM.load(name)
        m = screen(agent, STAND_PROMPT if floor else z, args.episodes, args.steps, args.seed)
        line = (f"{name}: got up {m['got_up']:.2f}, last-second pelvis {m['last_pelvis']:.2f} m, "
                f"stands {m['stand_s']:.1f} s")
        if demos is not None and isinstance(agent, BFM):
            d = demo_rises(agent, demos, args.steps)
            line += f"; demonstrations under their own z: got up {d['got_up']:.2f}, highest pelvis {d['highest']:.2f} m"
        print(f"{line} ({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
