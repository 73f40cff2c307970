"""lab/experiments/reinfer_prompts.py: some stored prompts regressed again, every other one kept as it was."""
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

from fbcpr import BFM

SCRIPT = Path(__file__).parents[1] / "experiments" / "reinfer_prompts.py"


def test_the_named_prompts_are_regressed_again_and_the_others_kept(tmp_path):
    out = tmp_path / "again"
    res = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(out), "--tasks", "raisearms-h-h,jump-2"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "raisearms-h-h: cosine of the new zero-shot z to the stored one" in res.stdout
    before = BFM.pretrained().reward_prompts
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # written with today's formula revisions: nothing stale
        after = BFM.load(out).reward_prompts
    # the re-inferred task's refinement is gone
    assert "raisearms-h-h" in before.refined
    assert sorted(after.refined) == sorted(set(before.refined) - {"raisearms-h-h"})
    assert after.revisions == before.revisions and after.states == before.states
    for task in ("raisearms-h-h", "jump-2"):  # the same states, so the regression gives the stored zero-shot z back
        z, z0 = after.z[task], before.zero_shot(task)
        assert z @ z0 / (np.linalg.norm(z) * np.linalg.norm(z0)) > 0.9999, task
    for task in set(before.z) - {"raisearms-h-h", "jump-2"}:
        np.testing.assert_array_equal(after.z[task], before.z[task])
