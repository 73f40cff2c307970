"""lab/experiments/carry_prompts.py: a continuation with B frozen takes its base's stored prompts, and only then."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.inference.reward_prompts import infer_reward_prompts, weights_digest
from tests.conftest import tiny_humanoid_checkpoint

SCRIPT = Path(__file__).parents[1] / "experiments" / "carry_prompts.py"
TASKS = ["move-ego-0-0", "move-ego-0-2"]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300)


def test_a_continued_actor_takes_its_bases_prompts_and_a_moved_b_is_refused(tmp_path: Path) -> None:
    base = BFM.load(tiny_humanoid_checkpoint(tmp_path, "raw", seed=0))
    base.reward_prompts = infer_reward_prompts(base, TASKS)
    base.save(tmp_path / "base")
    cand = BFM.load(tmp_path / "base")
    with torch.no_grad():                          # a continuation: the actor moved, B and the normaliser did not
        for p in cand.model.actor.parameters():
            p.add_(0.01)
    cand.save(tmp_path / "cand")
    assert BFM.load(tmp_path / "cand").reward_prompts is None   # another model's prompts are dropped on save
    res = run(str(tmp_path / "cand"), str(tmp_path / "base"), "--out", str(tmp_path / "carried"))
    assert res.returncode == 0, res.stderr
    carried = BFM.load(tmp_path / "carried")
    assert carried.reward_prompts is not None and carried.reward_prompts.digest == weights_digest(carried.model)
    for task in TASKS:
        np.testing.assert_array_equal(carried.prompt.reward(task), base.prompt.reward(task))
    assert not torch.equal(next(carried.model.actor.parameters()), next(base.model.actor.parameters()))
    with torch.no_grad():                          # B moved: its zero-shot prompts are not the base's
        next(cand.model.backward_map.parameters()).add_(0.01)
    cand.save(tmp_path / "moved")
    res = run(str(tmp_path / "moved"), str(tmp_path / "base"), "--out", str(tmp_path / "x"))
    assert res.returncode != 0 and "does not prompt as" in res.stderr and "backward_map." in res.stderr
    assert not (tmp_path / "x").exists()
