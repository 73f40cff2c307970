"""How long the humanoid stays upright under the stand prompt, next to the floor baselines of the same run.

For each agent (the zero-action and random floors, then checkpoints) prompted with `move-ego-0-0`: seconds
until the pelvis drops below 0.6 m from standing starts (median, mean ± std), and the share of fall starts
after which the pelvis stays above 0.8 m over the whole last second (got up). See fbcpr.eval.upright.

`--probe` asks whether a model's balance, or its getting up, depends on its prompt at all: for each checkpoint,
seconds upright from standing starts and the share of fall starts that got up, also under goal poses (`--goal`),
the imitation z of a clip (`--clip`) and random unit z's.

    python lab/experiments/upright_time.py runs/cpu-rest/checkpoints/step_0000100352 pretrained --episodes 16
    python lab/experiments/upright_time.py pretrained --probe --clip data/clips/deepmimic/walk.npz --episodes 8
    python lab/experiments/upright_time.py pretrained --probe --goal a_pose --clip data/clips/mixed/getup_facedown.npz

`--out FILE.json` also writes each agent's numbers (seconds upright, fall starts got up and, with `--push`, the
pushed starts held for the whole episode) with the settings, for `lab/experiments/compare_targets.py --pushes`.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import EPISODE_STEPS
from fbcpr.eval.upright import STAND_PROMPT, fall_starts_got_up, pelvis_heights, seconds_upright, upright
from humanoid_env.model import CONTROL_HZ


def probe_prompts(agent: Any, goals: list[str], clip: str | None, random_z: int, seed: int) -> dict[str, np.ndarray]:
    """z's beside the stand reward's: goal poses, a clip's imitation z and random unit z's."""
    zs = {f"goal {g}": agent.goal_z(g) for g in goals}
    if clip is not None:
        from motions.clip import load_clip

        zs[f"imitate {clip}"] = agent.imitate_z(load_clip(clip))
    rng = np.random.default_rng(seed)
    for i in range(random_z):
        zs[f"random z {i}"] = agent.project_z(rng.standard_normal(agent.z_dim))
    return zs


def print_row(label: str, agent: Any, init: Any, args: argparse.Namespace, prompt: str | np.ndarray = STAND_PROMPT,
              whole: bool = False, falls: bool = False) -> np.ndarray:
    """One row: seconds upright of `agent` from `init` starts under `prompt`; `whole` adds how many episodes stayed
    up to the end, `falls` the share of fall starts (those of `upright`) that got up under the same prompt.
    Returns the seconds upright per episode."""
    sec = seconds_upright(pelvis_heights(agent, init, args.episodes, args.steps, args.seed, prompt))
    end = f" (whole {args.steps / CONTROL_HZ:g} s: {held_whole(sec, args.steps)}/{len(sec)})" if whole else ""
    if falls:
        end += f" {fall_starts_got_up(agent, args.episodes, args.steps, args.seed, prompt).mean():7.2f}"
    print(f"{label:60s} {np.median(sec):9.2f} {sec.mean():8.2f} ± {sec.std():4.2f}{end}", flush=True)
    return sec


def held_whole(seconds: np.ndarray, steps: int) -> int:
    """Episodes that stayed upright to their last step."""
    return int((seconds >= steps / CONTROL_HZ).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agents", nargs="*", help="checkpoint dirs, run dirs or 'pretrained' (zero and random always run)")
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--probe", action="store_true", help="also other prompts than the stand reward (checkpoints only)")
    ap.add_argument("--goal", nargs="+", default=["t_pose"], help="with --probe: the goal poses probed")
    ap.add_argument("--clip", help="with --probe: a clip .npz whose imitation z is probed")
    ap.add_argument("--random-z", type=int, default=2, help="with --probe: how many random unit z's")
    ap.add_argument("--push", type=float, nargs=2, metavar=("ANGLE", "VEL"),
                    help="also from pushed standing starts: joint-angle noise (rad) and velocity noise of DefaultInit, "
                         "where the zero action falls too")
    ap.add_argument("--out", type=Path, help="also write the numbers of every agent to this JSON file")
    args = ap.parse_args()
    from humanoid_env.inits import DefaultInit

    print(f"{'agent':60s} {'median s':>9s} {'mean ± std s':>14s} {'got up':>7s}")
    results: dict[str, Any] = {"settings": {"episodes": args.episodes, "steps": args.steps, "seed": args.seed,
                                            "push": args.push}}
    for spec in ["zero", "random", *args.agents]:
        agent = make_agent(spec, seed=args.seed)
        res = upright(agent, args.episodes, args.steps, args.seed)
        print(f"{spec:60s} {res.median_seconds:9.2f} {res.seconds.mean():8.2f} ± {res.seconds.std():4.2f} "
              f"{res.share_got_up:7.2f}", flush=True)
        row = results[spec] = {"seconds": res.seconds.tolist(), "got_up": int(res.got_up.sum())}
        if args.push:
            pushed = print_row("  pushed start", agent, DefaultInit(*args.push), args, whole=True)
            row["pushed_held"] = held_whole(pushed, args.steps)
        if not args.probe or spec in ("zero", "random"):
            continue
        for name, z in probe_prompts(agent, args.goal, args.clip, args.random_z, args.seed).items():
            print_row("  z = " + name, agent, DefaultInit(), args, prompt=z, falls=True)
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
