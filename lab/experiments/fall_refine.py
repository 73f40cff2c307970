"""Getting up: a missing skill or a missing prompt, searched from fall starts.

The package refines a prompt from standing starts (`fbcpr.inference.refine.standing_starts`); getting up starts on
the floor. This runs the same cross-entropy search from fall starts (`humanoid_env.inits.FallInit`): z0 is a task's
prompt (the stand prompt, which the get-up check asks with), the objective a reward that pays every centimetre of
rise (`head-1.4` by default). It prints each generation and saves the best z for
`z_search.py --families get_up --judge Z.npy` to judge on fresh fall starts.

`--z0-file` starts the search from any saved z instead (a z a screen found), and `--standing` rolls out from
standing starts (`standing_starts`, as the package's own refinement does) instead of falls.

    python lab/experiments/fall_refine.py pretrained --save runs/getup_z.npy
    python lab/experiments/fall_refine.py pretrained --z0-file runs/z44.npy --objective sitonground --standing \
        --starts 16 --generations 15 --seed 3 --save runs/sit44_z.npy
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fbcpr import BFM
from fbcpr.inference.refine import Search, refine, reward_objective, standing_starts
from humanoid_env.inits import FallInit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--z0", default="move-ego-0-0", help="the task whose prompt the search starts from")
    ap.add_argument("--z0-file", type=Path, help="start from this saved z (.npy) instead of --z0's prompt")
    ap.add_argument("--objective", default="head-1.4", help="the reward the search climbs")
    ap.add_argument("--standing", action="store_true", help="standing starts instead of fall starts")
    ap.add_argument("--generations", type=int, default=10)
    ap.add_argument("--population", type=int, default=16)
    ap.add_argument("--starts", type=int, default=8, help="starts each candidate is rolled out from")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--sigma", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=0, help="the search's seed; its fall starts are drawn with seed + 1")
    ap.add_argument("--save", type=Path, required=True, help="where the best z goes (.npy)")
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    starts = standing_starts(args.starts, args.seed + 1) if args.standing else \
        FallInit().sample(np.random.default_rng(args.seed + 1), args.starts)
    z0 = np.load(args.z0_file, allow_pickle=False).astype(np.float32) if args.z0_file else bfm.prompt.reward(args.z0)
    search = Search(generations=args.generations, population=args.population, sigma=args.sigma, seed=args.seed)

    def show(row: dict[str, float]) -> None:
        print(f"generation {row['generation']:.0f}: mean z {row['mean_score']:.3f}, best candidate "
              f"{row['best_score']:.3f}, sigma {row['sigma']:.3f}, cos to z0 {row['cosine_z0']:.3f}", flush=True)

    got = refine(bfm, z0, reward_objective(args.objective), starts, steps=args.steps,
                 search=search, on_generation=show)
    args.save.parent.mkdir(parents=True, exist_ok=True)
    np.save(args.save, got.z)
    kind = "standing" if args.standing else "fall"
    print(f"{args.objective} from {args.starts} {kind} starts: {got.score0:.3f} -> {got.score:.3f} "
          f"({got.episodes} episodes, cos(z, z0) {got.cosine:.3f}); z saved to {args.save}")


if __name__ == "__main__":
    main()
