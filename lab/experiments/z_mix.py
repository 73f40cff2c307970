"""z's between two prompts: project((1 - a) z_A + a z_B) onto the policy's sphere, saved for `z_search.py --judge`.

A family no single prompt passes may sit between two prompts that each do part of it (crouch: between the sit
prompt's low pelvis and the crouch prompt's upright stance).

    python lab/experiments/z_mix.py pretrained --prompts reward:sitonground reward:crouch-0 goal:crouch_low \\
        --alphas 0.25 0.5 0.75 --out runs/s56/mix
"""
from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np
from contact_sheet import prompt_zs

from fbcpr import BFM
from fbcpr.inference.refine import project


def prompt_z(bfm: BFM, spec: str) -> np.ndarray:
    """`reward:NAME`, `goal:NAME` or `z:FILE.npy` -> the (d,) z, resolved (and a z file checked) as the contact
    sheet resolves its prompts; a tracking prompt is a z per step, not one z to mix."""
    if spec.partition(":")[0] not in ("reward", "goal", "z"):
        raise SystemExit(f"--prompts: {spec!r} must be reward:NAME, goal:NAME or z:FILE.npy")
    return prompt_zs(bfm, spec, 1)[0][0].astype(np.float64)


def label(spec: str) -> str:
    """A file-name-safe label: `reward:NAME` -> `reward-NAME`, `z:DIR/FILE.npy` -> `z-FILE`."""
    kind, _, name = spec.partition(":")
    return f"{kind}-{Path(name).stem if kind == 'z' else name}".replace("/", "_")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--prompts", nargs="+", required=True, help="every pair of these is mixed")
    ap.add_argument("--alphas", type=float, nargs="+", default=[0.25, 0.4, 0.5, 0.6, 0.75])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    zs = {spec: prompt_z(bfm, spec) for spec in args.prompts}
    args.out.mkdir(parents=True, exist_ok=True)
    for a, b in itertools.combinations(args.prompts, 2):
        mixed = project(np.outer(1 - np.asarray(args.alphas), zs[a]) + np.outer(args.alphas, zs[b]))
        for alpha, z in zip(args.alphas, mixed):
            name = f"{label(a)}+{label(b)}@{alpha:g}"
            np.save(args.out / f"{name}.npy", z.astype(np.float32))
    print(f"{len(list(args.out.glob('*.npy')))} z's in {args.out}")


if __name__ == "__main__":
    main()
