"""Summaries, rich tables and matplotlib bar charts of benchmark results (per task and per category)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.table import Table

#: Per-clip imitation metrics (`fbcpr.metrics.imitation_scores`) averaged into the tracking summary.
IMITATION_KEYS = ("dtw", "sparc", "sparc_expert")


def summarize(results: dict[str, Any]) -> dict[str, Any]:
    """Suite-level means, and reward returns averaged per Table 19 category."""
    summary: dict[str, Any] = {}
    if "reward" in results:
        cats: dict[str, list[float]] = {}
        for r in results["reward"].values():
            cats.setdefault(r["category"], []).append(r["return_mean"])
        summary["reward"] = {"mean_return": float(np.mean([r["return_mean"] for r in results["reward"].values()])),
                             "categories": {c: {"tasks": len(v), "mean_return": float(np.mean(v))}
                                            for c, v in cats.items()}}
    if "goal" in results:
        g = results["goal"].values()
        summary["goal"] = {"success": float(np.mean([x["success"] for x in g])),
                           "proximity": float(np.mean([x["proximity"] for x in g]))}
    if "tracking" in results:
        t = results["tracking"].values()
        summary["tracking"] = {"success": float(np.mean([x["success"] for x in t])),
                               "emd": float(np.mean([x["emd"] for x in t])),
                               "emd_hold_first_pose": float(np.mean([x["emd_hold_first_pose"] for x in t]))}
        summary["tracking"].update({k: float(np.mean([x[k] for x in t])) for k in IMITATION_KEYS
                                    if all(k in x for x in t)})
    return summary


def json_safe(obj: Any) -> Any:
    """Replace inf/NaN by None so results.json stays strict JSON."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _table(title: str, columns: tuple[str, ...], text_columns: int = 1) -> Table:
    """A rich table whose first `text_columns` columns are names (left) and the rest numbers (right)."""
    table = Table(title=title)
    for i, col in enumerate(columns):
        table.add_column(col, justify="left" if i < text_columns else "right")
    return table


def print_report(results: dict[str, Any], console: Console | None = None) -> None:
    """Rich tables: one row per task, then one per category / suite."""
    con = console or Console()
    title = f"{results.get('agent', 'agent')}: {results.get('episodes')} episodes x {results.get('steps')} steps"
    if "reward" in results:
        table = _table(f"Reward tasks ({title})", ("task", "category", "return", "std"), text_columns=2)
        for task, r in results["reward"].items():
            table.add_row(task, r["category"], f"{r['return_mean']:.1f}", f"{r['return_std']:.1f}")
        con.print(table)
        cat = _table("Reward categories", ("category", "tasks", "mean return"))
        for c, v in results["summary"]["reward"]["categories"].items():
            cat.add_row(c, str(v["tasks"]), f"{v['mean_return']:.1f}")
        cat.add_row("all", str(len(results["reward"])), f"{results['summary']['reward']['mean_return']:.1f}")
        con.print(cat)
    if "goal" in results:
        table = _table(f"Goal poses ({title})", ("goal", "success", "proximity", "min d_smpl"))
        for name, g in results["goal"].items():
            md = g["min_distance"]
            table.add_row(name, f"{g['success']:.2f}", f"{g['proximity']:.3f}", "-" if md is None else f"{md:.2f}")
        s = results["summary"]["goal"]
        table.add_row("all", f"{s['success']:.2f}", f"{s['proximity']:.3f}", "")
        con.print(table)
    if "tracking" in results:
        table = _table(f"Tracking ({results.get('agent', 'agent')})",
                       ("clip", "frames", "success", "EMD", "EMD holding the first pose"))
        for name, t in results["tracking"].items():
            table.add_row(name, str(t["frames"]), f"{t['success']:.0f}", f"{t['emd']:.3f}",
                          f"{t['emd_hold_first_pose']:.3f}")
        s = results["summary"]["tracking"]
        table.add_row("all", "", f"{s['success']:.2f}", f"{s['emd']:.3f}", f"{s['emd_hold_first_pose']:.3f}")
        con.print(table)
        if "dtw" in s:
            con.print(f"imitation: DTW pose error {s['dtw']:.3f} m, SPARC {s['sparc']:.2f} "
                      f"(clips: {s['sparc_expert']:.2f})")
    by_reason: dict[str, list[str]] = {}
    for name, reason in results.get("skipped", {}).items():
        by_reason.setdefault(reason, []).append(name)
    for reason, names in by_reason.items():
        con.print(f"[yellow]skipped {len(names)}[/] ({', '.join(names)}): {escape(reason)}", highlight=False)


def _bars(path: Path, labels: list[str], values: list[float], ylabel: str, title: str,
          colors: list[str] | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6.0, 0.28 * len(labels) + 2), 4))
    ax.bar(range(len(labels)), values, color=colors)
    ax.set_xticks(range(len(labels)), labels, rotation=75, ha="right", fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_results(results: dict[str, Any], out: Path) -> list[Path]:
    """Bar charts: reward return per task (coloured by category) and per category, goal success and
    proximity per pose, tracking EMD per clip."""
    agent = results.get("agent", "agent")
    paths = []
    if "reward" in results:
        tasks = list(results["reward"])
        cats = sorted({results["reward"][t]["category"] for t in tasks})
        palette = {c: f"C{i % 10}" for i, c in enumerate(cats)}
        paths.append(_bars(out / "reward_tasks.png", tasks, [results["reward"][t]["return_mean"] for t in tasks],
                           "return (300 steps)", f"{agent}: reward tasks",
                           [palette[results["reward"][t]["category"]] for t in tasks]))
        cat = results["summary"]["reward"]["categories"]
        paths.append(_bars(out / "reward_categories.png", list(cat), [v["mean_return"] for v in cat.values()],
                           "mean return", f"{agent}: reward categories", [palette[c] for c in cat]))
    if "goal" in results:
        names = list(results["goal"])
        paths.append(_bars(out / "goal_proximity.png", names, [results["goal"][g]["proximity"] for g in names],
                           "proximity", f"{agent}: goal proximity"))
        paths.append(_bars(out / "goal_success.png", names, [results["goal"][g]["success"] for g in names],
                           "success rate", f"{agent}: goal success"))
    if "tracking" in results:
        names = list(results["tracking"])
        paths.append(_bars(out / "tracking_emd.png", names, [results["tracking"][c]["emd"] for c in names],
                           "EMD", f"{agent}: tracking EMD"))
    return paths
