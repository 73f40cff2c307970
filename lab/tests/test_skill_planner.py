"""lab/experiments/skill_planner.py: the crouch reference lowers into the goal pose and holds it, the family rules
judge planned motions as the behaviour suite does, and the script reports the zero action beside each seed."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import skill_planner

from humanoid_env.inits import DefaultInit
from humanoid_env.model import CONTROL_HZ
from humanoid_env.tasks.goals import goal_obs, goal_qpos

SCRIPT = Path(__file__).parents[1] / "experiments" / "skill_planner.py"


def test_crouch_reference_lowers_into_the_pose_then_holds_it() -> None:
    q, _ = DefaultInit(0.0, 0.0).sample(np.random.default_rng(0), 1)
    ref = skill_planner.crouch_reference("crouch_medium", q[0], frames=90, seconds=1.0)
    goal = goal_qpos("crouch_medium")
    assert ref.shape == (90, 76)
    np.testing.assert_allclose(ref[0], q[0])
    np.testing.assert_allclose(ref[CONTROL_HZ:, 2], goal[2])  # at the pose from one second on, and held
    np.testing.assert_allclose(ref[CONTROL_HZ:, 7:], np.broadcast_to(goal[7:], (90 - CONTROL_HZ, 69)))
    np.testing.assert_allclose(ref[:, :2], np.broadcast_to(q[0, :2], (90, 2)))  # lowered in place
    np.testing.assert_allclose(np.linalg.norm(ref[:, 3:7], axis=1), 1.0)
    assert np.all(np.diff(ref[:, 2]) <= 1e-12)


def test_the_crouch_rule_passes_a_held_crouch_and_fails_standing() -> None:
    ok, measures = skill_planner.judge("crouch", np.repeat(goal_obs("crouch_medium")[None], 60, 0))
    assert ok and measures["held"] == 1.0
    ok, measures = skill_planner.judge("crouch", np.repeat(goal_obs("crouch_high")[None], 60, 0))
    assert not ok and measures["held"] == 0.0  # pelvis 0.80 m: a bent-knee stand, not a crouch


def test_the_script_reports_the_zero_action_and_each_seed(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--skill", "crouch", "--ramp", "0.5", "--seeds", "0",
                          "--steps", "40", "--threads", "1", "--planner", "samples=2", "horizon=4"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert re.search(r"^  zero action: fail \{'pelvis': 0\.9\d+, 'held': 0\.0\}$", out, re.M), out
    assert re.search(r"^  planner seed 0: (PASS|fail) \{'pelvis': [\d.]+, 'held': [\d.]+\}  pelvis min", out, re.M)
    assert re.search(r"^crouch: [01] of 1 planned motions pass$", out, re.M), out
    bad = subprocess.run([sys.executable, str(SCRIPT), "--skill", "crouch", "--ramp", "0"], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and "--ramp must be > 0" in bad.stderr
