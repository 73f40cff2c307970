"""lab/experiments/cross_prompt.py: one model's actor on another model's prompts."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.conftest import humanoid_states, tiny_humanoid_checkpoint
from fbcpr import BFM
from fbcpr.core.checkpoint import CheckpointError
from humanoid_env.tasks import goal_obs

SCRIPT = Path(__file__).parents[1] / "experiments" / "cross_prompt.py"
spec = importlib.util.spec_from_file_location("cross_prompt", SCRIPT)
cross_prompt = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cross_prompt)
torch.set_num_threads(1)


def test_the_crossed_agent_acts_with_one_model_on_the_others_latents(tmp_path):
    a, b = BFM.load(tiny_humanoid_checkpoint(tmp_path, "a", 0)), BFM.load(tiny_humanoid_checkpoint(tmp_path, "b", 1))
    crossed = cross_prompt.CrossedAgent(a, b)
    g = goal_obs("t_pose")
    z = crossed.goal_z(g)
    np.testing.assert_array_equal(z, b.goal_z(g))
    assert not np.allclose(z, a.goal_z(g))
    obs = humanoid_states(5, seed=3)["next_obs"]
    zs = np.repeat(z[None], 5, 0)
    np.testing.assert_array_equal(crossed.act(obs, zs), a.act(obs, zs))
    assert not np.allclose(crossed.act(obs, zs), b.act(obs, zs))
    np.testing.assert_array_equal(crossed.reward_z("jump-2"), b.reward_z("jump-2"))
    with pytest.raises(CheckpointError, match="action mapping differs"):
        cross_prompt.CrossedAgent(a, BFM.load(tiny_humanoid_checkpoint(tmp_path, "mid", 2, mapping="mid")))


def test_the_script_prints_the_three_rows(tmp_path):
    from motions.clip import save_clip
    from motions.synthetic import stand

    save_clip(stand(1.0), tmp_path / "clips" / "stand.npz")
    a, b = tiny_humanoid_checkpoint(tmp_path, "a", 0), tiny_humanoid_checkpoint(tmp_path, "b", 1)
    out = subprocess.run([sys.executable, str(SCRIPT), str(a), str(b), "--suite", "goal", "--episodes", "1",
                          "--steps", "5", "--motions", str(tmp_path / "clips"), "--threads", "1"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line.split(":")[0].strip() for line in out.stdout.splitlines() if '"goal"' in line]
    assert rows == ["actor's own", "prompter's own", "crossed"], out.stdout
