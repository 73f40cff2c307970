"""lab/experiments/getup_screen.py: the shipped model and the zero action stand under the stand prompt and neither
gets up from the floor; a script line per agent."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import getup_screen
import numpy as np

from fbcpr import BFM
from fbcpr.eval.agents import ZeroAgent
from fbcpr.eval.upright import STAND_PROMPT
from humanoid_env.model import default_qpos
from motions.clip import from_qpos, save_clip
from motions.library import MotionLibrary

SCRIPT = Path(__file__).parents[1] / "experiments" / "getup_screen.py"


def test_shipped_model_stands_and_stays_down_from_falls() -> None:
    bfm = BFM.pretrained()
    m = getup_screen.screen(bfm, bfm.reward_z(STAND_PROMPT), episodes=2, steps=60, seed=0)
    assert m["stand_s"] == 2.0  # the whole 60 steps from the quiet standing start
    assert m["got_up"] == 0.0 and m["last_pelvis"] < 0.6  # the fall starts lie at the floor
    floor = getup_screen.screen(ZeroAgent(), STAND_PROMPT, episodes=2, steps=60, seed=0)
    assert floor["got_up"] == 0.0 and floor["stand_s"] == 2.0


def test_a_standing_clip_under_its_own_z_stays_up(tmp_path: Path) -> None:
    save_clip(from_qpos(np.repeat(default_qpos()[None], 12, 0), "still"), tmp_path / "still.npz")
    d = getup_screen.demo_rises(BFM.pretrained(), MotionLibrary.load(tmp_path), steps=60)
    assert d["got_up"] == 1.0 and d["highest"] > 0.8


def test_prints_a_line_per_agent_and_refuses_a_short_episode(tmp_path: Path) -> None:
    save_clip(from_qpos(np.repeat(default_qpos()[None], 12, 0), "still"), tmp_path / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", "--episodes", "2", "--steps", "60",
                          "--demos", str(tmp_path)], capture_output=True, text=True, timeout=300, check=True).stdout
    assert re.search(r"^zero action: got up [\d.]+, last-second pelvis [\d.]+ m, stands [\d.]+ s \(", out, re.M), out
    assert re.search(r"^pretrained: got up [\d.]+, last-second pelvis [\d.]+ m, stands [\d.]+ s; demonstrations "
                     r"under their own z: got up [\d.]+, highest pelvis [\d.]+ m", out, re.M), out
    bad = subprocess.run([sys.executable, str(SCRIPT), "pretrained", "--steps", "30"], capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode != 0 and "--steps" in bad.stderr
