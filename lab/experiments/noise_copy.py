"""A copy of a model whose actor weights carry tiny Gaussian noise: the same policy, for sizing evaluation noise.

    python lab/experiments/noise_copy.py pretrained runs/S3p --sigma 1e-5 --seed 7

The humanoid's physics is chaotic, so an action change of 1e-4 sends a 300-step rollout elsewhere. Measured like a
candidate (`lab/experiments/targets.py`, `lab/experiments/upright_time.py`), such a copy differs from its model only by that
noise: a candidate must beat the copies' spread before its gain means anything (`compare_targets.py --noise`;
lab/log.md section 27). Only the actor changes, so every prompt infers the same z's; the copy carries the
model's reward sample (all of it, up to --reward-samples states).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from fbcpr.inference.bfm import BFM


def noise_copy(model: BFM, sigma: float, seed: int) -> BFM:
    """`model` (changed in place, and returned) with N(0, sigma^2) added to every actor weight."""
    if not np.isfinite(sigma) or sigma < 0:
        raise SystemExit(f"--sigma: must be a finite number >= 0, got {sigma}")
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.model.actor.parameters():
            p.add_(torch.randn(p.shape, generator=gen, dtype=p.dtype) * sigma)
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="checkpoint dir or 'pretrained'")
    ap.add_argument("out", help="where the copy is written")
    ap.add_argument("--sigma", type=float, default=1e-5, help="std of the noise on each actor weight")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reward-samples", type=int, default=50_000, help="states of the reward sample the copy keeps")
    args = ap.parse_args()
    model = BFM.load(args.model)
    obs = np.random.default_rng(args.seed).standard_normal((256, model.obs_dim)).astype(np.float32)
    z = model.project_z(np.random.default_rng(args.seed + 1).standard_normal((256, model.z_dim)))
    before = model.act(obs, z)
    noise_copy(model, args.sigma, args.seed).save(args.out, reward_samples=args.reward_samples)
    print(f"{args.out}: actions changed by {float(((model.act(obs, z) - before) ** 2).mean()):.2e} "
          "(mean squared, per component, on 256 random states and z's)")


if __name__ == "__main__":
    main()
