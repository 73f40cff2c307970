"""lab/experiments/goal_inference.py end to end on a tiny checkpoint: each method on the same starts as the model's own."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import tiny_humanoid_checkpoint, two_clips  # noqa: F401 (a fixture)
from fbcpr.inference.bfm import BFM
from fbcpr.eval.runner import evaluate
from humanoid_env.tasks import GOALS
from motions.library import MotionLibrary

BENCH = Path(__file__).parents[1] / "experiments" / "goal_inference.py"


def test_each_goal_method_is_scored_beside_the_backward_reference(tmp_path, two_clips):
    ckpt = tiny_humanoid_checkpoint(tmp_path, "tiny", seed=0)
    out = tmp_path / "goals.json"
    run = subprocess.run([sys.executable, str(BENCH), str(ckpt), "--motions", str(two_clips), "--seeds", "3",
                          "--methods", "mix", "--episodes", "2", "--steps", "3", "--threads", "1", "--out", str(out)],
                         check=True, capture_output=True, text=True)
    assert "backward" in run.stdout and "mix" in run.stdout  # the reference runs although not asked for
    results = json.loads(out.read_text())["results"]
    assert set(results) == {"backward", "mix"}
    assert set(results["mix"]["3"]["poses"]) == set(GOALS)
    direct = evaluate(BFM.load(ckpt), "goal", episodes=2, motions=MotionLibrary.load(two_clips), steps=3, seed=3,
                      show_progress=False, num_threads=1)
    assert results["backward"]["3"]["success"] == pytest.approx(direct["summary"]["goal"]["success"])
    assert results["backward"]["3"]["proximity"] == pytest.approx(direct["summary"]["goal"]["proximity"])
    assert results["mix"]["3"]["proximity"] != pytest.approx(direct["summary"]["goal"]["proximity"])
