"""Time to relabel a 100k-sample buffer with rewards from the registry, next to plain numpy passes over the
same array measured in the same run.

    python benchmarks/reward_relabel.py [--n 100000] [--repeats 3]

The buffer holds real humanoid observations (goal poses and built-in motion clips, with noise on the
velocities so that movement terms vary), in float32 as a replay buffer stores them.
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from humanoid_env.tasks import GOALS, TASKS, get_reward, goal_obs

FEATURED = ["move-ego-0-2", "move-ego-low-90-2", "jump-2", "rotate-y-5-0.8", "raisearms-h-l", "crouch-0",
            "sitonground", "lieonground-up", "split-1", "crawl-0.4-2-d", "handstand",
            "move-ego-0-2-raisearms-h-h", "move-ego-0-2*raisearms-h-h+jump-2"]


def make_buffer(n: int, rng: np.random.Generator) -> np.ndarray:
    from motions.synthetic import default_clips

    base = np.concatenate([np.stack([goal_obs(g) for g in GOALS])] + [c.obs for c in default_clips()])
    obs = base[rng.integers(0, len(base), n)].astype(np.float32)
    obs[:, 214:] += rng.normal(scale=0.5, size=(n, 144)).astype(np.float32)
    return obs


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    obs = make_buffer(args.n, np.random.default_rng(0))
    print(f"buffer: {obs.shape} float32, {obs.nbytes / 1e6:.0f} MB; python {platform.python_version()}, "
          f"numpy {np.__version__}; best of {args.repeats}")
    ref_sum = best_of(lambda: obs.sum(axis=1), args.repeats)
    ref_norm = best_of(lambda: np.linalg.norm(obs[:, :214], axis=1), args.repeats)
    print(f"{'reference: obs.sum(axis=1)':44s} {ref_sum * 1e3:8.1f} ms")
    print(f"{'reference: norm of the pose part':44s} {ref_norm * 1e3:8.1f} ms")
    for name in FEATURED:
        fn = get_reward(name)
        t = best_of(lambda: fn(obs), args.repeats)
        print(f"{name:44s} {t * 1e3:8.1f} ms  ({t / ref_norm:5.1f}x the norm pass)")
    fns = [get_reward(t) for t in TASKS]
    t_all = best_of(lambda: [f(obs) for f in fns], 1)
    print(f"{f'all {len(TASKS)} tasks of Tables 18 and 25':44s} {t_all * 1e3:8.1f} ms  "
          f"({t_all / len(TASKS) * 1e3:.1f} ms per task)")


if __name__ == "__main__":
    main()
