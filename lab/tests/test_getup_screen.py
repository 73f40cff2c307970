"""lab/experiments/getup_screen.py: the shipped model and the zero action stand under the stand prompt and neither
gets up from the floor; a script line per agent."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import getup_screen
from fbcpr import BFM
from fbcpr.eval.agents import ZeroAgent
from fbcpr.eval.upright import STAND_PROMPT

SCRIPT = Path(__file__).parents[1] / "experiments" / "getup_screen.py"


def test_shipped_model_stands_and_stays_down_from_falls() -> None:
    bfm = BFM.pretrained()
    m = getup_screen.screen(bfm, bfm.reward_z(STAND_PROMPT), episodes=2, steps=60, seed=0)
    assert m["stand_s"] == 2.0  # the whole 60 steps from the quiet standing start
    assert m["got_up"] == 0.0 and m["last_pelvis"] < 0.6  # the fall starts lie at the floor
    floor = getup_screen.screen(ZeroAgent(), STAND_PROMPT, episodes=2, steps=60, seed=0)
    assert floor["got_up"] == 0.0 and floor["stand_s"] == 2.0


def test_prints_a_line_per_agent_and_refuses_a_short_episode() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", "--episodes", "2", "--steps", "30"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    for name in ("zero action", "pretrained"):
        assert re.search(rf"^{name}: got up [\d.]+, last-second pelvis [\d.]+ m, stands [\d.]+ s", out, re.M), out
    bad = subprocess.run([sys.executable, str(SCRIPT), "pretrained", "--steps", "20"], capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode != 0 and "--steps" in bad.stderr
