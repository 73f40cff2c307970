"""lab/experiments/getup_planner.py: one line per start and planner seed, and the motions that end up saved as
demonstrations that replay in the env."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from humanoid_env.env import HumanoidEnv
from humanoid_env.model import default_qpos
from motions.clip import from_qpos, save_clip
from motions.demonstrations import load_demonstrations

SCRIPT = Path(__file__).parents[1] / "experiments" / "getup_planner.py"


def test_a_standing_start_stays_up_and_is_saved_as_a_demonstration_that_replays(tmp_path):
    clip = from_qpos(np.repeat(default_qpos()[None], 10, 0), "still")  # a "rise" that is already up
    save_clip(clip, tmp_path / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "--clip", str(tmp_path / "still.npz"), "--fractions", "0", "1",
                          "--seeds", "0", "--steps", "31", "--samples", "3", "--horizon", "4", "--threads", "1",
                          "--save", str(tmp_path / "demos")],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert len(re.findall(r"zero action UP +max", out)) == 2, out
    assert len(re.findall(r"^  planner seed 0: UP +max [\d.]+ last [\d.]+", out, re.M)) == 2, out
    assert out.strip().endswith("up, of 1 seeds: fraction 0.00: 1, fraction 1.00: 1")
    demos = load_demonstrations(tmp_path / "demos")
    assert [d.clip.name for d in demos] == ["still_planned_fraction_0.00_s0", "still_planned_fraction_1.00_s0"]
    env = HumanoidEnv()
    env.reset(options={"qpos": demos[0].clip.qpos[0], "qvel": demos[0].clip.qvel[0]})
    for a in demos[0].actions:
        info = env.step(a)[4]
    np.testing.assert_allclose(info["qpos"], demos[0].clip.qpos[-1], atol=1e-6)


def test_no_fractions_runs_only_the_fall_starts(tmp_path):
    clip = from_qpos(np.repeat(default_qpos()[None], 10, 0), "still")
    save_clip(clip, tmp_path / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "--clip", str(tmp_path / "still.npz"), "--fractions",
                          "--fall-starts", "1", "--seeds", "2", "--steps", "5", "--samples", "3", "--horizon", "4",
                          "--threads", "1"], capture_output=True, text=True, timeout=300, check=True).stdout
    assert "fraction" not in out, out
    assert re.search(r"^fall start 0 f2 \(frame 0, pelvis [\d.]+ m\): zero action", out, re.M), out
    assert re.search(r"up, of 1 seeds: fall start 0 f2: [01]$", out.strip()), out
