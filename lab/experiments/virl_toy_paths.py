"""Figure: the toy policies' paths over the demonstration (docs/img/virl_toy_paths.png).

    python lab/experiments/virl_toy_paths.py [--runs runs/imitation-toy] [--out docs/img/virl_toy_paths.png]

Reads the runs `lab/experiments/imitation_toy.py` wrote (RUNS/<method>/checkpoints/latest) and rolls each policy out
from the demo's first state for the demo's length (the evaluation's rollouts, `demo_rollouts`, seed 123), next to
a uniform random policy; one panel per method, the demonstration in grey under the agent's paths.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fbcpr.core.checkpoint import latest_checkpoint, load_checkpoint  # noqa: E402
from fbcpr.eval.toy import demo_rollouts, imitation_metrics  # noqa: E402
from fbcpr.envs.toy import demo_paths  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]  # the repository root: figures go to its docs/img/
METHODS = ("random", "amp", "virl-state", "virl-video")
EVAL_SEED = 123


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", default="runs/imitation-toy")
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "virl_toy_paths.png"))
    args = ap.parse_args()
    fig, axes = plt.subplots(1, len(METHODS), figsize=(3.2 * len(METHODS), 3.8))
    for ax, method in zip(axes, METHODS):
        model, demo = None, "circle-ccw"
        if method != "random":
            ckpt = load_checkpoint(latest_checkpoint(Path(args.runs) / method / "checkpoints"))
            model, demo = ckpt.model.eval(), ckpt.config.env.motions
        ref = demo_paths()[demo]
        paths = demo_rollouts(model, demo, np.random.default_rng(EVAL_SEED))
        scores = imitation_metrics(model, demo, np.random.default_rng(EVAL_SEED))
        ax.plot(ref[:, 0], ref[:, 1], color="0.75", lw=6, label="demo")
        for p in paths[:5]:
            ax.plot(p[:, 0], p[:, 1], lw=1)
        ax.set_title(f"{method}\nDTW {scores['dtw']:.3f}, shape {scores['shape_coverage']:.0%}", fontsize=9)
        ax.set_xlim(-1, 1), ax.set_ylim(-1, 1), ax.set_aspect("equal"), ax.set_xticks([]), ax.set_yticks([])
    axes[0].legend(loc="lower left", fontsize=7)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
