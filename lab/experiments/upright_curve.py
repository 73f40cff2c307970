"""Upright time against updates over the checkpoints of one or more runs: the learning curve of balance.

For every `--every`-th checkpoint of each run (and always its last), the median seconds upright under the stand
prompt from standing starts, and with `--push` from pushed standing starts, where the zero action falls too. The
zero-action and random floors of the same starts are measured once. Writes a CSV and a PNG (one line per run,
floors dashed), so seeds of one config can be compared at a glance.

    python lab/experiments/upright_curve.py runs/td3-stand-s1 runs/td3-stand-s2 --episodes 8 --every 4 \
        --push 0.1 0.3 --out docs/img/upright_curve_td3_stand
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from fbcpr.core.checkpoint import list_checkpoints, read_trainer_meta
from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import EPISODE_STEPS
from fbcpr.eval.upright import pelvis_heights, seconds_upright
from humanoid_env.model import CONTROL_HZ


def checkpoints(run: Path, every: int) -> list[Path]:
    """Every `every`-th checkpoint folder of a run, oldest first, and always the newest."""
    found = list_checkpoints(run / "checkpoints")
    if not found:
        raise SystemExit(f"{run}: no checkpoints/step_* folders")
    return sorted(set(found[::every]) | {found[-1]})


def starts(push: list[float] | None) -> dict[str, object]:
    """The start distributions measured: standing still, and pushed when asked."""
    from humanoid_env.inits import DefaultInit

    out: dict[str, object] = {"standing": DefaultInit()}
    if push:
        out["pushed"] = DefaultInit(*push)
    return out


def measure(spec: str, inits: dict[str, object], args: argparse.Namespace) -> dict[str, float]:
    """Median seconds upright and the share of whole episodes, per start distribution."""
    agent = make_agent(spec, seed=args.seed)
    row: dict[str, float] = {}
    for name, init in inits.items():
        sec = seconds_upright(pelvis_heights(agent, init, args.episodes, args.steps, args.seed))
        row[f"{name}_median_s"] = float(np.median(sec))
        row[f"{name}_whole"] = float(np.mean(sec >= args.steps / CONTROL_HZ))
    return row


def plot(rows: list[dict], floors: dict[str, dict[str, float]], inits: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(inits), figsize=(5.5 * len(inits), 4), squeeze=False)
    for ax, name in zip(axes[0], inits):
        for run in dict.fromkeys(r["run"] for r in rows):
            mine = [r for r in rows if r["run"] == run]
            ax.plot([r["updates"] for r in mine], [r[f"{name}_median_s"] for r in mine], marker="o", label=run)
        for floor, style in (("zero", "--"), ("random", ":")):
            ax.axhline(floors[floor][f"{name}_median_s"], color="grey", linestyle=style, label=f"{floor} action")
        ax.set(xlabel="gradient updates", ylabel="median seconds upright", title=f"stand prompt, {name} starts",
               ylim=(0, None))
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run directories (with checkpoints/step_*)")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--steps", type=int, default=EPISODE_STEPS)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=int, default=1, help="evaluate every k-th checkpoint (and the last)")
    ap.add_argument("--push", type=float, nargs=2, metavar=("ANGLE", "VEL"), help="also pushed standing starts")
    ap.add_argument("--out", type=Path, default=Path("upright_curve"), help="writes OUT.csv and OUT.png")
    args = ap.parse_args()
    if args.every < 1:
        raise SystemExit("--every must be at least 1")
    inits = starts(args.push)
    floors = {spec: measure(spec, inits, args) for spec in ("zero", "random")}
    print("floors:", {k: {m: round(v, 2) for m, v in row.items()} for k, row in floors.items()}, flush=True)
    rows = []
    for run in args.runs:
        for ckpt in checkpoints(run, args.every):
            meta = read_trainer_meta(ckpt)
            row = {"run": run.name, "env_steps": meta["env_steps"], "updates": meta["updates"],
                   **measure(str(ckpt), inits, args)}
            rows.append(row)
            print(", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
        for name, row in floors.items():
            writer.writerow({"run": f"{name} action", **row})
    plot(rows, floors, list(inits), args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
