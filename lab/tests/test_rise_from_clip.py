"""lab/experiments/rise_from_clip.py: starts along a clip, and what the zero action does from them."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).parents[1] / "experiments" / "rise_from_clip.py"
spec = importlib.util.spec_from_file_location("rise_from_clip", SCRIPT)
rise_from_clip = importlib.util.module_from_spec(spec)
spec.loader.exec_module(rise_from_clip)


def test_frames_near_stay_inside_the_clip_and_centre_on_the_fraction():
    assert rise_from_clip.frames_near(0.0, 91, 8).tolist() == list(range(8))
    assert rise_from_clip.frames_near(1.0, 91, 8).tolist() == list(range(83, 91))
    assert rise_from_clip.frames_near(0.5, 91, 8).tolist() == list(range(41, 49))  # centre frame 45
    assert rise_from_clip.frames_near(0.5, 5, 8).tolist() == [0, 1, 2, 3, 4, 0, 1, 2]  # a short clip repeats


def test_zero_action_stays_up_only_from_standing_frames(tmp_path):
    """A clip that lies for its first half and stands for its second: the zero action (rest pose) stays up from
    the standing frames and not from the lying ones."""
    from humanoid_env.inits import FallInit
    from motions.clip import from_qpos, save_clip
    from motions.synthetic import stand

    standing = stand(1.0)
    lying, _ = FallInit().sample(np.random.default_rng(0), 1)
    q = np.concatenate([np.repeat(lying, 30, 0), standing.qpos[:30]])
    q[:30, :3] = [*standing.qpos[0, :2], 0.12]  # lying on the floor where the standing half stands
    save_clip(from_qpos(q, name="half", source="test", license="MIT"), tmp_path / "half.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "--clip", str(tmp_path / "half.npz"), "--fractions", "0", "1",
                          "--episodes", "2"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    zero = next(line for line in out.stdout.splitlines() if line.startswith("zero")).split()
    assert zero[1] == "0" and zero[3] == "2", out.stdout  # 0 of 2 up from lying, 2 of 2 from standing
    bad = subprocess.run([sys.executable, str(SCRIPT), "--clip", str(tmp_path / "half.npz"), "--fractions", "1.5"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--fractions" in bad.stderr
