"""NPMP latent optimisation (paper Sec. 3.3, Eq. 10): for clips where one-shot tracking fails, optimise the latent
sequence against the expert's nominal actions and track again; prints EMD of the expert, of one-shot NPMP tracking
and of the optimised latents, and how much of the gap to the expert the optimisation closes.

    python lab/experiments/npmp_latent_opt.py runs/npmp-bc --motions data/clips/deepmimic --clips jump,kick

Ends with lines `RESULT clip=<name> metric=relative_emd oneshot=<x> optimised=<y>` (EMD_expert / EMD, 1 = expert).
"""
from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.inference.agents import load_tracker
from fbcpr.eval.runner import tracking_suite
from fbcpr.apps.npmp.data import collect
from fbcpr.apps.npmp.latent_opt import optimise_latents
from motions.library import MotionLibrary
from rich.progress import Progress


class GivenLatents:
    """The NPMP's decoder driven by a fixed latent sequence instead of its encoder's."""

    def __init__(self, agent: Any, zs: np.ndarray) -> None:
        self.agent, self.zs = agent, zs
        self.z_dim, self.action_mapping = agent.z_dim, agent.action_mapping

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> np.ndarray:
        return self.agent.act(obs, z)

    def track_z(self, obs_seq: np.ndarray) -> np.ndarray:
        return self.zs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("npmp")
    parser.add_argument("--motions", required=True)
    parser.add_argument("--clips", required=True, help="comma-separated clip names")
    parser.add_argument("--expert", default=None, help="default: the NPMP's recorded expert")
    parser.add_argument("--steps", type=int, default=300, help="Adam steps of the latent optimisation")
    args = parser.parse_args()
    torch.set_num_threads(1)
    agent = load_tracker(args.npmp)
    expert = BFM.load(args.expert or agent.info.get("expert", "pretrained"))
    library = MotionLibrary.load(args.motions)
    by_name = {c.name: c for c in library.clips}
    lines = []
    with Progress(transient=True) as bar:
        for name in args.clips.split(","):
            clip = by_name[name]
            nominal = collect(expert, MotionLibrary([clip]), "bc", rollouts=1, noise=0.0, max_steps=clip.n_frames)
            states, actions = nominal.obs, nominal.action  # the expert's states and actions from frame 0
            oneshot = agent.track_z(clip.obs)
            z0 = torch.as_tensor(oneshot[np.minimum(np.arange(len(states)), len(oneshot) - 1)])
            z, before, after = optimise_latents(agent.model, states, actions, z0, steps=args.steps)
            zs = z.numpy()[np.minimum(np.arange(clip.n_frames - 1), len(z) - 1)]
            emd = {k: tracking_suite(a, [clip], bar)[name]["emd"]
                   for k, a in (("expert", expert), ("oneshot", agent), ("optimised", GivenLatents(agent, zs)))}
            print(f"{name}: action MSE {before:.4f} -> {after:.4f}; EMD expert {emd['expert']:.3f}, one-shot "
                  f"{emd['oneshot']:.3f}, optimised {emd['optimised']:.3f}")
            lines.append(f"RESULT clip={name} metric=relative_emd oneshot={emd['expert'] / emd['oneshot']:.3f} "
                         f"optimised={emd['expert'] / emd['optimised']:.3f}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
