"""lab/experiments/clip_playback.py: a clip's joint angles as open-loop PD targets."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).parents[1] / "experiments" / "clip_playback.py"
spec = importlib.util.spec_from_file_location("clip_playback", SCRIPT)
clip_playback = importlib.util.module_from_spec(spec)
spec.loader.exec_module(clip_playback)


def test_the_body_holds_the_clip_poses_that_the_zero_action_would_leave():
    """A held crouch keeps the pelvis at the clip's 0.66 m, where the zero action (the rest pose's targets) stands
    up past 0.9 m; a standing clip stands."""
    from humanoid_env.env import HumanoidEnv
    from humanoid_env.tasks import goal_qpos
    from motions.clip import from_qpos
    from motions.synthetic import stand

    env = HumanoidEnv(max_episode_steps=200)
    crouch = from_qpos(np.repeat(goal_qpos("crouch_medium")[None], 30, 0), name="crouch", source="test", license="MIT")
    held = clip_playback.playback(env, crouch, 0, after=30)
    standing = stand(1.0)
    up = clip_playback.playback(env, standing, 0, after=30)
    assert len(held) == 29 + 30 and len(up) == standing.n_frames - 1 + 30
    assert 0.6 < held.min() and held.max() < 0.7, (held.min(), held.max())
    assert up.min() > 0.85


def test_the_script_prints_one_row_per_start_and_rejects_frames_outside_the_clip(tmp_path):
    from motions.clip import save_clip
    from motions.synthetic import stand

    save_clip(stand(1.0), tmp_path / "stand.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "stand.npz"), "--starts", "0", "10",
                          "--after", "5"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line.split() for line in out.stdout.splitlines()[2:]]
    assert [r[0] for r in rows] == ["0", "10"] and all(float(r[2]) > 0.85 for r in rows), out.stdout
    bad = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "stand.npz"), "--starts", "30"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--starts" in bad.stderr
