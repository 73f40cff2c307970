"""How long the humanoid stays upright under the stand prompt, next to the floor baselines of the same run.

For each agent (the zero-action and random floors, then checkpoints) prompted with `move-ego-0-0`: seconds
until the pelvis drops below 0.6 m from standing starts (median, mean ± std), and the share of fall starts
after which the pelvis stays above 0.8 m over the whole last second (got up). See fbcpr.evaluation.upright.

    python benchmarks/upright_time.py runs/cpu-rest/checkpoints/step_0000100352 pretrained --episodes 16
"""
from __future__ import annotations

import argparse

from fbcpr.evaluation.agents import make_agent
from fbcpr.evaluation.upright import upright


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("agents", nargs="*", help="checkpoint dirs, run dirs or 'pretrained' (zero and random always run)")
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"{'agent':60s} {'median s':>9s} {'mean ± std s':>14s} {'got up':>7s}")
    for spec in ["zero", "random", *args.agents]:
        res = upright(make_agent(spec, seed=args.seed), args.episodes, args.steps, args.seed)
        print(f"{spec:60s} {res.median_seconds:9.2f} {res.seconds.mean():8.2f} ± {res.seconds.std():4.2f} "
              f"{res.share_got_up:7.2f}", flush=True)


if __name__ == "__main__":
    main()
