"""Where a prompted body goes: the root's horizontal path over the last seconds, per episode.

A spin check reads the yaw rate only; this tells a turn on the spot from running round a wide circle.

    python lab/experiments/root_path.py pretrained --reward rotate-z-5-0.8 --seed 46
"""
from __future__ import annotations

import argparse

import numpy as np

from fbcpr import BFM
from fbcpr.eval import behaviours as B
from humanoid_env.model import CONTROL_HZ


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--reward", required=True, help="the reward prompt to roll out")
    ap.add_argument("--seed", type=int, default=0, help="standing starts as the behaviour suite draws them")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--last", type=float, default=5.0, help="seconds at the end the path is read over")
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    z = bfm.prompt.reward(args.reward)
    qpos, qvel = B.start_states(args.episodes, args.seed)["standing"]
    xy = np.zeros((args.steps + 1, args.episodes, 2))

    def keep(t: int, envs: slice, obs: np.ndarray, q: np.ndarray, dead: np.ndarray) -> None:
        xy[t + 1, envs] = q[:, :2]

    B.run_batch(bfm, B.Batch(z=np.repeat(z[None], args.episodes, 0), qpos=qpos, qvel=qvel), args.steps, keep)
    last = xy[-int(args.last * CONTROL_HZ):]
    centre = last.mean(0)
    radius = np.linalg.norm(last - centre, axis=-1)
    path = np.linalg.norm(np.diff(last, axis=0), axis=-1).sum(0)
    print(f"last {args.last:g} s, per episode:")
    print("  distance from its own centre, mean (m):", np.round(radius.mean(0), 2))
    print("  distance from its own centre, max (m): ", np.round(radius.max(0), 2))
    print("  path length (m):                       ", np.round(path, 1))
    print("  centre's drift from the start (m):     ", np.round(np.linalg.norm(centre - xy[0], axis=-1), 2))


if __name__ == "__main__":
    main()
