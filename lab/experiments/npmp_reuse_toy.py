"""NPMP reuse on the toy (issue 12, the paper's Sec. 4.3 / Fig. 6 claim): TD3 acting in an NPMP's latent space
through the AR(1) prior (`env.npmp`, `fbcpr.apps.npmp.reuse`) against TD3 on raw actions, same config, same env steps.

The NPMP is distilled with LFPC (1 nominal rollout per demonstration, every toy demo) from a trained toy FB-CPR
teacher, with the networks of lab/experiments/npmp_toy.py, and saved to OUT/npmp (reused if there). Then, per seed,
both TD3 runs train on `--task` from fbcpr/configs/td3-toy.yaml, evaluated every `--eval-every` env steps: mean return
of 10 episodes x 100 steps from uniform random starts (deterministic policy), and the env actions' mean change per
step. The random policy of each action space is the reference measured in the same run.

    python lab/experiments/npmp_reuse_toy.py runs/toy-bench/seed0/checkpoints/step_0000060000 --out runs/npmp-reuse-toy

Writes OUT/curves.json and a plot (--plot), and ends with
`RESULT agent=td3-<raw|npmp> task=<task> steps=<n> metric=return value=<mean over seeds>` per evaluation step.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.core.config import find_config, load_config
from fbcpr.envs.bundle import make_env
from fbcpr.apps.npmp.checkpoint import is_npmp_checkpoint, save_npmp
from fbcpr.apps.npmp.config import npmp_config
from fbcpr.apps.npmp.data import collect
from fbcpr.apps.npmp.distill import Distiller
from fbcpr.apps.npmp.model import NPMPModel
from fbcpr.apps.npmp.reuse import task_return
from fbcpr.envs import toy as pm
from fbcpr.train.trainer import Trainer
from npmp_toy import TOY_NPMP, ToyClip

EPISODES, HORIZON = 10, 100


def distil(teacher_path: str, out: Path, steps: int, seed: int, alpha: float) -> Path:
    """An LFPC NPMP of the teacher on every toy demonstration, saved at `out` (kept if already there)."""
    if is_npmp_checkpoint(out):
        print(f"reusing the NPMP at {out}")
        return out
    start = time.time()
    teacher = BFM.load(teacher_path)
    demos = pm.demo_paths()
    library = SimpleNamespace(clips=[ToyClip(n, d) for n, d in demos.items()], names=list(demos))
    data = collect(teacher, library, "lfpc", rollouts=1, noise=0.1, perturb_scale=0.1, seed=seed,
                   make_env=lambda n, k: pm.PointMassVectorEnv(n, max_episode_steps=k))
    torch.manual_seed(seed)
    cfg = npmp_config({**TOY_NPMP, "seed": seed, "alpha": alpha}, preset="paper")
    model = NPMPModel(cfg, pm.OBS_DIM, pm.ACTION_DIM)
    model.obs_normalizer.update(data.obs)
    distiller = Distiller(model, data)
    for _ in range(steps):
        metrics = distiller.update()
    save_npmp(out, model, {"expert": teacher_path, "method": "lfpc", "steps": steps, "clips": list(demos),
                           "metrics": metrics})
    print(f"distilled {out}: {len(data.obs)} states, action MSE {metrics['mse']:.4f}, KL {metrics['kl']:.2f} "
          f"({time.time() - start:.0f} s)")
    return out


def run(cfg: Any, out: Path, task: str, seed: int, episodes: int = EPISODES,
        horizon: int = HORIZON) -> tuple[list[int], list[dict[str, float]], float]:
    """Train one TD3 run, evaluating at step 0 and every cfg.train.eval_every env steps (`episodes` episodes of
    `horizon` steps): (steps, rows, seconds)."""
    bundle = make_env(cfg.env, 1, seed)
    steps: list[int] = []
    curve: list[dict[str, float]] = []

    def evaluate(agent: Any) -> dict[str, float]:
        row = task_return(lambda obs: agent.model.act(obs, mean=True), bundle, task, episodes, horizon, seed=1000)
        steps.append(trainer.env_steps)
        curve.append(row)
        return row

    start = time.time()
    trainer = Trainer(cfg, out, evaluate=evaluate, progress=False)
    evaluate(trainer.agent)
    trainer.run()
    trainer.close()
    return steps, curve, time.time() - start


def random_reference(cfg: Any, task: str, episodes: int = EPISODES, horizon: int = HORIZON) -> dict[str, float]:
    bundle = make_env(cfg.env, 1, 0)
    rng = np.random.default_rng(0)
    return task_return(lambda obs: rng.uniform(-1, 1, (len(obs), bundle.action_dim)).astype(np.float32), bundle,
                       task, episodes, horizon, seed=1000)


def plot_panel(ax: Any, curves: dict[str, Any], task: str, horizon: int = HORIZON) -> None:
    """Return vs env steps per agent: the mean over seeds, a min-max band, and the random policy dotted."""
    for name, c in curves.items():
        r = np.array([[row["return"] for row in seed_curve] for seed_curve in c["seeds"].values()])
        ax.plot(c["steps"], r.mean(0), label=f"{name} ({len(r)} seeds)")
        ax.fill_between(c["steps"], r.min(0), r.max(0), alpha=0.2)
        ax.axhline(c["random"]["return"], ls=":", color=ax.lines[-1].get_color(), lw=1)
    ax.set_xlabel("env steps")
    ax.set_ylabel(f"return ({task}, {horizon} steps)")
    ax.legend()


def plot(curves: dict[str, Any], task: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    plot_panel(ax, curves, task)
    ax.set_title("TD3 in NPMP latent space vs raw actions (toy)\nmean, min-max band; dotted: random policy",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("teacher", help="a toy FB-CPR checkpoint (fbcpr/configs/toy.yaml)")
    parser.add_argument("--out", type=Path, default=Path("runs/npmp-reuse-toy"))
    parser.add_argument("--task", default="reach-top-right", help=f"a toy task: {sorted(pm.TASKS)}")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=10_000, help="env steps per TD3 run")
    parser.add_argument("--eval-every", type=int, default=1000)
    parser.add_argument("--distill-steps", type=int, default=1500)
    parser.add_argument("--alpha", type=float, default=0.95, help="the distilled NPMP's AR(1) prior (0: i.i.d.)")
    parser.add_argument("--plot", type=Path, default=None, help="learning-curve PNG")
    parser.add_argument("--scale", type=float, default=None, help="env.npmp_innovation_scale (default: the config's)")
    parser.add_argument("--action-penalty", type=float, default=0.0,
                        help="agent.action_penalty; in z-space a pull toward the prior, as ||eps||^2 is its KL")
    parser.add_argument("--agents", nargs="+", default=["td3-raw", "td3-npmp"], choices=["td3-raw", "td3-npmp"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    npmp = distil(args.teacher, args.out / "npmp", args.distill_steps, 0, args.alpha)
    base = load_config(find_config("td3-toy"))
    base = replace(base, agent=replace(base.agent, reward=replace(base.agent.reward, task=args.task),
                                       action_penalty=args.action_penalty),
                   train=replace(base.train, total_env_steps=args.steps, eval_every=args.eval_every))
    scale = base.env.npmp_innovation_scale if args.scale is None else args.scale
    configs = {"td3-raw": base, "td3-npmp": replace(base, env=replace(base.env, npmp=str(npmp),
                                                                       npmp_innovation_scale=scale))}
    configs = {name: configs[name] for name in args.agents}
    curves: dict[str, Any] = {}
    for name, cfg in configs.items():
        curves[name] = {"random": random_reference(cfg, args.task), "seeds": {}, "seconds": {}}
        for seed in args.seeds:
            seeded = replace(cfg, train=replace(cfg.train, seed=seed))
            steps, curve, secs = run(seeded, args.out / f"{name}-seed{seed}", args.task, seed)
            curves[name].update(steps=steps)
            curves[name]["seeds"][seed], curves[name]["seconds"][seed] = curve, secs
            print(f"{name} seed {seed} ({secs:.0f} s): return " + " ".join(f"{r['return']:.1f}" for r in curve)
                  + f"; action change at the end {curve[-1]['action_change']:.3f}")
    (args.out / "curves.json").write_text(json.dumps({"task": args.task, **curves}, indent=1))
    if args.plot is not None:
        plot(curves, args.task, args.plot)
    for name, c in curves.items():
        print(f"RESULT agent=random-{name[4:]} task={args.task} metric=return value={c['random']['return']:.2f}")
        for i, step in enumerate(c["steps"]):
            r = [seed_curve[i]["return"] for seed_curve in c["seeds"].values()]
            print(f"RESULT agent={name} task={args.task} steps={step} metric=return value={np.mean(r):.2f}")


if __name__ == "__main__":
    main()
