"""One-shot tracking of an NPMP scored against its expert (paper Sec. 3.2, Fig. 4: performance relative to the
expert), with the tracking metrics of the FB-CPR benchmark: both agents go through the same runner
(`fbcpr.eval.runner.tracking_suite`: each clip from its first frame, EMD and success per clip).

EMD is a cost, so the relative score of a clip is EMD_expert / EMD_npmp: 1 is expert level, below 1 worse,
like the paper's return ratio. Clips the NPMP was distilled on are `train`, the others `held_out`."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def relative_to_expert(npmp: dict[str, dict[str, float]], expert: dict[str, dict[str, float]],
                       train_clips: Sequence[str]) -> dict[str, Any]:
    """Per clip and per split (train / held_out / all): EMD and success of both, and the NPMP's relative score."""
    clips = {}
    for name in npmp.keys() & expert.keys():
        n, e = npmp[name], expert[name]
        clips[name] = {"split": "train" if name in train_clips else "held_out", "emd": n["emd"],
                       "emd_expert": e["emd"], "success": n["success"], "success_expert": e["success"],
                       "relative_emd": e["emd"] / n["emd"] if n["emd"] > 0 else 1.0}
    summary = {}
    for split in ("train", "held_out", "all"):
        rows = [c for c in clips.values() if split in ("all", c["split"])]
        if not rows:
            continue
        col = {k: np.array([r[k] for r in rows], dtype=np.float64) for k in rows[0] if k != "split"}
        summary[split] = {"clips": len(rows), "emd": float(col["emd"].mean()),
                          "emd_expert": float(col["emd_expert"].mean()),
                          "relative_emd_median": float(np.median(col["relative_emd"])),
                          "success": float(col["success"].mean()),
                          "success_expert": float(col["success_expert"].mean())}
    return {"clips": dict(sorted(clips.items())), "summary": summary}
