"""Learning curves from what runs logged while training: chosen metrics.csv keys against env steps and wall-clock.

One row of panels per metric: against env steps, and against hours of training (`wall_s`, summed over a run's
resumes; runs logged before it existed are drawn against env steps only). One line per run, so seeds or arms of a
config compare at a glance, without evaluating any checkpoint again (`train.eval_upright` logs
`eval/upright_s` and `eval/upright_pushed_s` during training, `train.eval_tasks` returns and goal success;
lab/experiments/upright_curve.py measures checkpoints afterwards). Patterns such as `'eval/return/*'` pick every
matching key.

    python lab/experiments/training_curves.py runs/td3-stand-s3 runs/rfs-F --metrics eval/upright_s \
        eval/upright_pushed_s --out docs/img/training_curves
    python lab/experiments/training_curves.py runs/rfs-E --metrics 'eval/return/*' eval/goal_success --out runs/E
"""
from __future__ import annotations

import argparse
import csv
import fnmatch
from collections import defaultdict
from pathlib import Path


def read_metrics(run: Path) -> dict[str, dict[int, float]]:
    """metrics.csv of a run as {key: {env_steps: value}} (a later row for the same step wins, as after a resume)."""
    path = run / "metrics.csv"
    if not path.is_file():
        raise SystemExit(f"{run}: no metrics.csv (not a training run directory?)")
    out: dict[str, dict[int, float]] = defaultdict(dict)
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            out[row["key"]][int(row["env_steps"])] = float(row["value"])
    return out


def series(logged: dict[str, dict[int, float]], key: str) -> list[tuple[int, float | None, float]]:
    """(env steps, hours of training or None, value) for every logged value of `key`."""
    wall = logged.get("wall_s", {})
    return [(step, wall[step] / 3600 if step in wall else None, v) for step, v in sorted(logged.get(key, {}).items())]


def expand(patterns: list[str], keys: set[str]) -> list[str]:
    """The metrics asked for, with shell-style patterns (`eval/return/*`) replaced by the logged keys they match."""
    out: list[str] = []
    for pattern in patterns:
        found = sorted(fnmatch.filter(keys, pattern)) if any(c in pattern for c in "*?[") else [pattern]
        if not found:
            raise SystemExit(f"--metrics {pattern!r} matches no logged key (logged: {', '.join(sorted(keys))})")
        out += [k for k in found if k not in out]
    return out


def plot(curves: dict[str, dict[str, list]], metrics: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import EngFormatter

    timed = any(p[1] is not None for by_key in curves.values() for pts in by_key.values() for p in pts)
    fig, axes = plt.subplots(len(metrics), 1 + timed, figsize=(5.5 * (1 + timed), 3.6 * len(metrics)), squeeze=False)
    for row, key in zip(axes, metrics):
        for run, by_key in curves.items():
            pts = by_key[key]
            row[0].plot([p[0] for p in pts], [p[2] for p in pts], marker="o", markersize=3, label=run)
            if timed:
                mine = [p for p in pts if p[1] is not None]
                row[1].plot([p[1] for p in mine], [p[2] for p in mine], marker="o", markersize=3, label=run)
        row[0].set(xlabel="env steps", ylabel=key)
        row[0].xaxis.set_major_formatter(EngFormatter())  # 400k, 1M: raw step counts run into each other
        if timed:
            row[1].set(xlabel="hours of training (wall_s)", ylabel=key)
        for ax in row:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="run directories (with metrics.csv)")
    ap.add_argument("--metrics", nargs="+", required=True,
                    help="metrics.csv keys or patterns, e.g. eval/upright_s 'eval/return/*' reward")
    ap.add_argument("--out", type=Path, default=Path("training_curves"), help="writes OUT.csv and OUT.png")
    args = ap.parse_args()
    runs = {run: read_metrics(run) for run in args.runs}
    metrics = expand(args.metrics, set().union(*runs.values()))
    curves = {}
    for run, logged in runs.items():
        missing = [k for k in metrics if k not in logged]
        if missing:
            raise SystemExit(f"{run}/metrics.csv: no {', '.join(missing)} (logged: {', '.join(sorted(logged))})")
        curves[run.name] = {k: series(logged, k) for k in metrics}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["run", "metric", "env_steps", "hours", "value"])
        for run, by_key in curves.items():
            for key, pts in by_key.items():
                writer.writerows([run, key, step, "" if h is None else f"{h:.4f}", v] for step, h, v in pts)
    plot(curves, metrics, args.out.with_suffix(".png"))
    for run, by_key in curves.items():
        for key, pts in by_key.items():
            top = max(p[2] for p in pts)
            print(f"{run:24s} {key:24s} last {pts[-1][2]:.3g} at {pts[-1][0]:,} env steps, max {top:.3g}")
    print(f"wrote {args.out.with_suffix('.csv')} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
