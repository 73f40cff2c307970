"""NPMP on the toy (issue 12, evidence 1; the paper's Fig. 3 comparison): distil a trained toy FB-CPR model into an
NPMP with BC from 1, 10 and 100 noisy rollouts per demonstration and with LFPC from 1 nominal rollout, then track
demonstrations one-shot: the 4 distilled on and 3 held out. Error = mean position error per step from the demo's
first state (the toy's `track_error`); relative_to_teacher = error_teacher / error_npmp (1 = teacher level).

    python lab/experiments/npmp_toy.py runs/toy-bench/seed0/checkpoints/step_0000060000 --steps 1500

Ends with `RESULT method=npmp-<bc|lfpc> rollouts=<n> metric=relative_to_teacher value=<x>` (held-out demos), and
the same with `split=train`.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Callable

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.apps.npmp.config import npmp_config
from fbcpr.apps.npmp.data import collect
from fbcpr.apps.npmp.distill import Distiller
from fbcpr.apps.npmp.model import NPMPModel
from fbcpr.envs import toy as pm

TRAIN = ("circle-ccw", "figure-eight", "sweep-top", "sweep-left")
TOY_NPMP = dict(latent_dim=16, encoder_hidden=128, decoder_hidden=128, seq_length=16, batch_size=64, lr=1e-3)


@dataclass
class ToyClip:
    """A demonstration with the per-frame state a rollout starts from (qvel: the last displacement)."""

    name: str
    obs: np.ndarray

    @property
    def n_frames(self) -> int:
        return len(self.obs)

    @property
    def qpos(self) -> np.ndarray:
        return self.obs.astype(np.float64)

    @property
    def qvel(self) -> np.ndarray:
        return np.vstack([np.zeros((1, pm.NV)), np.diff(self.qpos, axis=0)])


def held_out(length: int = 200) -> dict[str, np.ndarray]:
    """Demonstrations the NPMP never sees: the small circle, a diagonal sweep and a circle on the left."""
    t = np.arange(length, dtype=np.float64)
    return {"circle-cw-small": pm.demo_paths(length)["circle-cw-small"],
            "diagonal": np.stack([0.7 * np.sin(0.05 * t), 0.7 * np.sin(0.05 * t)], 1).astype(np.float32),
            "circle-left": (np.array([-0.3, 0.1]) + 0.35 * np.stack([np.cos(0.08 * t), np.sin(0.08 * t)], 1)
                            ).astype(np.float32)}


def track_error(act: Callable[[np.ndarray, int], np.ndarray], demos: list[np.ndarray]) -> np.ndarray:
    """(n_demos,) mean position error of a policy act(obs (n, 2), t) from each demo's first state."""
    T = len(demos[0])
    env = pm.PointMassVectorEnv(len(demos), max_episode_steps=T + 1)
    obs, _ = env.reset(options={"qpos": np.stack([d[0] for d in demos]), "qvel": np.zeros((len(demos), pm.NV))})
    err = np.zeros(len(demos))
    for t in range(T - 1):
        obs, *_ = env.step(act(obs, t))
        err += np.linalg.norm(obs - np.stack([d[t + 1] for d in demos]), axis=1)
    return err / (T - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("teacher", help="a toy FB-CPR checkpoint (fbcpr/configs/toy.yaml)")
    parser.add_argument("--steps", type=int, default=1500, help="gradient steps per NPMP")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    teacher = BFM.load(args.teacher)
    demos = pm.demo_paths()
    train = [ToyClip(n, demos[n]) for n in TRAIN]
    test = [ToyClip(n, d) for n, d in held_out().items()]
    library = SimpleNamespace(clips=train, names=list(TRAIN))
    splits = {"train": train, "held_out": test}

    def teacher_act(clips: list[ToyClip]) -> Callable[[np.ndarray, int], np.ndarray]:
        zs = np.stack([teacher.prompt.track(c) for c in clips])
        return lambda obs, t: teacher.act(obs, zs[:, t])

    rng = np.random.default_rng(args.seed)
    base = {s: track_error(teacher_act(c), [x.obs for x in c]) for s, c in splits.items()}
    rand = {s: track_error(lambda obs, t: rng.uniform(-1, 1, obs.shape), [x.obs for x in c]) for s, c in splits.items()}
    print(f"teacher error: train {base['train'].mean():.3f}, held out {base['held_out'].mean():.3f}; random: train "
          f"{rand['train'].mean():.3f}, held out {rand['held_out'].mean():.3f}")
    lines = [f"RESULT method=random rollouts=0 metric=relative_to_teacher value="
             f"{base['held_out'].mean() / rand['held_out'].mean():.3f}"]
    cfg = npmp_config({**TOY_NPMP, "seed": args.seed}, preset="paper")
    for method, rollouts in (("lfpc", 1), ("bc", 1), ("bc", 10), ("bc", 100)):
        start = time.time()
        data = collect(teacher, library, method, rollouts=rollouts, noise=0.1, perturb_scale=0.1, seed=args.seed,
                       make_env=lambda n, steps: pm.PointMassVectorEnv(n, max_episode_steps=steps))
        torch.manual_seed(args.seed)
        model = NPMPModel(cfg, pm.OBS_DIM, pm.ACTION_DIM)
        model.obs_normalizer.update(data.obs)
        distiller = Distiller(model, data)
        for _ in range(args.steps):
            metrics = distiller.update()
        errors = {}
        for split, clips in splits.items():
            zs = [model.encode(torch.as_tensor(c.obs)).numpy() for c in clips]
            z_all = np.stack(zs)
            errors[split] = track_error(lambda obs, t: model.act(torch.as_tensor(obs), torch.as_tensor(z_all[:, t])
                                                                 ).numpy(), [c.obs for c in clips])
        rel = {s: base[s].mean() / errors[s].mean() for s in splits}
        print(f"npmp-{method} rollouts={rollouts}: {len(data.obs)} states, action MSE {metrics['mse']:.4f}, error "
              f"train {errors['train'].mean():.3f} held out {errors['held_out'].mean():.3f} "
              f"({time.time() - start:.0f} s)")
        lines.append(f"RESULT method=npmp-{method} rollouts={rollouts} metric=relative_to_teacher "
                     f"value={rel['held_out']:.3f}")
        lines.append(f"RESULT method=npmp-{method} rollouts={rollouts} split=train metric=relative_to_teacher "
                     f"value={rel['train']:.3f}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
