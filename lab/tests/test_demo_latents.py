"""lab/experiments/demo_latents.py: each clip's two z's are saved and the pelvis is printed once a second."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from humanoid_env.model import default_qpos
from motions.clip import from_qpos, save_clip

SCRIPT = Path(__file__).parents[1] / "experiments" / "demo_latents.py"


def test_saves_both_zs_per_clip_and_prints_a_height_per_second(tmp_path: Path) -> None:
    (tmp_path / "clips").mkdir()
    save_clip(from_qpos(np.repeat(default_qpos()[None], 12, 0), "still"), tmp_path / "clips" / "still.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "clips"), "--steps", "60",
                          "--out", str(tmp_path / "z")], capture_output=True, text=True, timeout=300, check=True).stdout
    assert sorted(p.name for p in (tmp_path / "z").iterdir()) == ["imitate_still.npy", "track_end_still.npy"]
    for name in ("imitate_still", "track_end_still"):
        heights = re.search(rf"^{name}: pelvis each second \[([\d., ]+)\]$", out, re.M)
        assert heights, out
        assert len(heights.group(1).split(",")) == 2  # 60 steps: the heights at 1 s and 2 s
        assert np.load(tmp_path / "z" / f"{name}.npy").shape == (64,)
