"""lab/experiments/demo_latents.py: each clip's z's are saved and the pelvis is printed once a second, with its
highest point after the first."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from humanoid_env.model import default_qpos
from motions.clip import from_qpos, save_clip

SCRIPT = Path(__file__).parents[1] / "experiments" / "demo_latents.py"


def test_saves_each_z_per_clip_and_prints_a_height_per_second(tmp_path: Path) -> None:
    (tmp_path / "clips").mkdir()
    save_clip(from_qpos(np.repeat(default_qpos()[None], 12, 0), "still"), tmp_path / "clips" / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "clips"), "--steps", "60",
                          "--frames", "3", "--out", str(tmp_path / "z")],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    names = ["imitate_still", "track_003_still", "track_end_still"]
    assert sorted(p.name for p in (tmp_path / "z").iterdir()) == [f"{n}.npy" for n in names]
    for name in names:
        line = re.search(rf"^{name}: pelvis each second \[([\d., ]+)\], highest ([\d.]+) after the first second$",
                         out, re.M)
        assert line, out
        heights = [float(h) for h in line.group(1).split(",")]
        assert len(heights) == 2  # 60 steps: the heights at 1 s and 2 s
        assert float(line.group(2)) >= heights[1]
        assert np.load(tmp_path / "z" / f"{name}.npy").shape == (64,)


def test_a_frame_past_the_clip_is_refused(tmp_path: Path) -> None:
    (tmp_path / "clips").mkdir()
    save_clip(from_qpos(np.repeat(default_qpos()[None], 12, 0), "still"), tmp_path / "clips" / "still.npz")
    run = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "clips"), "--frames", "11",
                          "--out", str(tmp_path / "z")], capture_output=True, text=True, timeout=300)
    assert run.returncode != 0 and "frames 0-10" in run.stderr


def test_track_reads_the_jump_rule_off_a_step_by_step_rollout(tmp_path: Path) -> None:
    (tmp_path / "clips").mkdir()
    save_clip(from_qpos(np.repeat(default_qpos()[None], 45, 0), "still"), tmp_path / "clips" / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "clips"), "--steps", "40",
                          "--track", "--out", str(tmp_path / "z")],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    line = re.search(r"^tracked still: apex ([+-][\d.]+) m over standing, (\d+) flight steps, jump rule (\w+)$",
                     out, re.M)
    assert line, out
    assert abs(float(line.group(1))) < 0.1 and line.group(3) == "failed"  # a body holding still does not jump


def test_a_run_shorter_than_a_second_is_refused(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path), "--steps", "30",
                          "--out", str(tmp_path / "z")], capture_output=True, text=True, timeout=300)
    assert run.returncode != 0 and "--steps" in run.stderr
