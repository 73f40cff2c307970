"""lab/experiments/funnel_rise.py: rises that end up are built into a library and the rest left out; the states an
agent holds from become handoff states; the evaluation runs the agent alone and the library before it."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from humanoid_env.env import HumanoidEnv
from humanoid_env.inits import FallInit
from lqr import StabilisedTrajectory
from humanoid_env.model import NU, default_qpos
from motions.clip import from_qpos
from motions.demonstrations import Demonstration, save_demonstration

SCRIPT = Path(__file__).parents[1] / "experiments" / "funnel_rise.py"


def run(*args: str) -> str:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=600,
                          check=True).stdout


def test_build_mark_and_eval(tmp_path):
    env = HumanoidEnv()
    fall_q, fall_v = FallInit().sample(np.random.default_rng(0), 1)
    env.reset(options={"qpos": fall_q[0], "qvel": fall_v[0]})
    for _ in range(60):
        env.step(np.zeros(NU))
    lying = env.data.qpos.copy()
    demos = tmp_path / "demos"
    for name, pose in (("still", default_qpos()), ("lying", lying)):
        clip = from_qpos(np.repeat(pose[None], 32, 0), name)
        save_demonstration(Demonstration(clip, np.zeros((31, NU), np.float32), "rest"), demos / f"{name}.npz")
    lib = tmp_path / "lib"
    out = run("build", str(demos), "--out", str(lib), "--settle", "2", "--threads", "1",
              "--planner", "samples=3", "horizon=4")
    assert re.search(r"^lying: left out, does not end up", out, re.M), out
    assert re.search(r"^still: 33 steps, end pelvis 0\.9\d m", out, re.M), out
    assert sorted(p.name for p in lib.iterdir()) == ["still.npz"]
    assert StabilisedTrajectory.load(lib / "still.npz").handoff is None

    def evaluate() -> tuple[int, int, float, int, float]:
        text = run("eval", str(lib), "zero", "--episodes", "4", "--steps", "35")
        alone = int(re.search(r"agent alone +up +(\d+) of 4", text).group(1))
        rows = [re.search(name + r" +up +(\d+) of 4 \([\d.]+\), library acting (\d+)% of steps", text)
                for name in ("library, then agent", r"\.\.\. agent keeps bodies")]
        return alone, int(rows[0].group(1)), float(rows[0].group(2)), int(rows[1].group(1)), float(rows[1].group(2))

    # unmarked, a trajectory hands over only at its last steps: the library acts on the fall starts
    unmarked = evaluate()
    assert unmarked[2] > 0 and unmarked[4] > 0
    out = run("mark", str(lib), "zero", "--stride", "10")
    assert "still.npz: held from 4 of 4 checked states, first handoff at step 0 of 33" in out, out
    assert StabilisedTrajectory.load(lib / "still.npz").handoff.all()
    # the zero action holds from every state of a stand: the library hands every state over, and the two rows agree
    alone, with_library, acting, holding, acting_held = evaluate()
    assert acting == 0 and acting_held == 0 and with_library == holding == alone
