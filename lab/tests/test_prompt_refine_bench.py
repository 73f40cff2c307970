"""lab/experiments/prompt_refine.py end to end on a tiny checkpoint, and contact_sheet.py's `z:FILE.npy` prompts."""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import tiny_humanoid_checkpoint, two_clips  # noqa: F401 (a fixture)
from fbcpr.inference.bfm import BFM
from fbcpr.eval.runner import evaluate
from motions.library import MotionLibrary

BENCH = Path(__file__).parents[1] / "experiments"


def _module(name: str):
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_benchmark_scores_both_prompts_on_the_same_starts(tmp_path, two_clips):
    ckpt = tiny_humanoid_checkpoint(tmp_path, "tiny", seed=0)
    out = tmp_path / "refine.json"
    subprocess.run([sys.executable, str(BENCH / "prompt_refine.py"), str(ckpt), "--motions", str(two_clips),
                    "--tasks", "move-ego-0-2", "--goals", "t_pose", "--generations", "1", "--population", "2",
                    "--starts", "1", "--steps", "5", "--held-out", "2", "--eval-seeds", "0", "--episodes", "1",
                    "--threads", "1", "--out", str(out)], check=True, capture_output=True, text=True)
    rows = json.loads(out.read_text())["rows"]
    assert [(r["task"], r["kind"]) for r in rows] == [("move-ego-0-2", "reward"), ("t_pose", "goal")]
    reward, goal = rows
    assert reward["episodes"] == 3 and reward["train_score"] >= reward["train_score0"]
    assert set(goal["refined_test"][0]) == {"success", "proximity"}
    # z0's held-out row is the zero-shot model's own evaluation on the same starts
    bfm = BFM.load(ckpt)
    direct = evaluate(bfm, "reward", tasks=["move-ego-0-2"], episodes=2, motions=MotionLibrary.load(two_clips),
                      steps=5, fall_prob=0.0, seed=100, show_progress=False, num_threads=1)
    assert reward["z0_held_out"]["return"] == pytest.approx(direct["reward"]["move-ego-0-2"]["return_mean"])


def test_contact_sheet_rolls_out_a_saved_z(tmp_path):
    sheet = _module("contact_sheet")
    bfm = BFM.load(tiny_humanoid_checkpoint(tmp_path, "tiny", seed=1))
    path = tmp_path / "z.npy"
    np.save(path, 3.0 * np.ones(bfm.z_dim, np.float32))
    zs, start, clip = sheet.prompt_zs(bfm, f"z:{path}", 4)
    assert zs.shape == (4, bfm.z_dim) and start is None and clip is None
    np.testing.assert_allclose(zs[0], np.ones(bfm.z_dim), rtol=1e-6)  # projected onto the sqrt(d) sphere
    np.save(path, np.ones(bfm.z_dim + 1, np.float32))
    with pytest.raises(SystemExit, match=r"z\.npy must hold one finite z"):
        sheet.prompt_zs(bfm, f"z:{path}", 4)
