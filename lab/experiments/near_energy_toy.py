"""The learned NEAR energy over the toy arena at three noise levels, with the demonstration on top.

    python lab/experiments/near_energy_toy.py [--out docs/img/near_energy_toy.png] [--seed 0]

Pretrains the energy of fbcpr/configs/near-toy.yaml on the circle-ccw demonstration (as a run's first update does),
then draws, at sigma_1, a middle level and sigma_L, the energy e((s, s' - s), sigma) of the best step at each
arena position s (over 16 directions at the demonstration's speed), with arrows along that step. All panels
share one colour scale, so the sharper levels show as narrower high-energy bands around the demonstration.
Prints the pretraining losses and the energy on the demonstration, off it, and standing still on it.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from fbcpr.core.config import find_config, load_config  # noqa: E402
from fbcpr.rewards.near.reward import NEARReward  # noqa: E402
from fbcpr.envs import toy as pm  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]  # the repository root: figures go to its docs/img/
GRID, DIRECTIONS = 41, 16


def best_steps(near: NEARReward, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid positions (G, G, 2), the highest unconditional energy over the candidate steps (G, G), and that step."""
    axis = np.linspace(-1, 1, GRID, dtype=np.float32)
    pos = np.stack(np.meshgrid(axis, axis), -1)                                        # (G, G, 2)
    angles = np.linspace(0, 2 * np.pi, DIRECTIONS, endpoint=False)
    steps = speed * np.stack([np.cos(angles), np.sin(angles)], -1).astype(np.float32)  # (K, 2)
    s = torch.as_tensor(np.repeat(pos.reshape(-1, 1, 2), DIRECTIONS, 1).reshape(-1, 2))
    e = near.anchored_energy(s, s + torch.as_tensor(np.tile(steps, (GRID * GRID, 1)))).reshape(GRID, GRID, -1)
    best = e.argmax(-1).numpy()
    return pos, e.max(-1).values.numpy(), steps[best]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "near_energy_toy.png"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = load_config(find_config("near-toy"))
    demo = pm.demo_paths()[cfg.env.motions]
    near = NEARReward(pm.OBS_DIM, cfg.agent.near, seed=args.seed,
                      library=pm.DemoLibrary({cfg.env.motions: demo}))
    print({k: round(v, 3) for k, v in near.pretrain().items()})
    d = torch.as_tensor(demo)
    for name, (s, s_next) in {"demo": (d[:-1], d[1:]), "shifted +0.3": (d[:-1] + 0.3, d[1:] + 0.3),
                              "standing still": (d[:-1], d[:-1]), "reversed": (d[1:], d[:-1])}.items():
        print(f"mean energy e(x) {name}: {near.anchored_energy(s, s_next).mean().item():.3f}")
    speed = float(np.linalg.norm(np.diff(demo, axis=0), axis=-1).mean())
    pos, energy, step = best_steps(near, speed)
    levels = [0, len(near.sigmas) // 2, len(near.sigmas) - 1]
    floor = energy.min() / near.sigmas[0].item()                                      # the sigma_1 panel's range
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4), constrained_layout=True)
    for ax, k in zip(axes, levels):
        sigma = near.sigmas[k].item()
        im = ax.imshow(energy / sigma, origin="lower", extent=(-1, 1, -1, 1), vmin=floor, vmax=0, cmap="viridis")
        ax.quiver(pos[::3, ::3, 0], pos[::3, ::3, 1], step[::3, ::3, 0], step[::3, ::3, 1], color="w", alpha=0.6,
                  scale=speed * 25)
        ax.plot(demo[:, 0], demo[:, 1], "r-", lw=1.5, label="demonstration (circle-ccw)")
        ax.set_title(f"level {k + 1}: sigma = {sigma:.3g}")
        ax.set_xticks([-1, 0, 1])
        ax.set_yticks([-1, 0, 1])
    axes[0].legend(loc="lower left", fontsize=8)
    fig.colorbar(im, ax=axes, shrink=0.9, label="e((s, s'-s), sigma) of the best step (0 = demo mean)")
    fig.suptitle("NEAR energy on the toy: best step at each position, arrows along it")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
