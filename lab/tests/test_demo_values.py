"""lab/experiments/demo_values.py: a TD3 checkpoint's Q on the demonstrations it trained on, next to their returns."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.conftest import two_clips  # noqa: F401 (a fixture)
from fbcpr.train.trainer import Trainer
from motions.demonstrations import save_demonstration
from tests.test_demonstrations import humanoid_cfg, planned  # noqa: F401 (a fixture)

SCRIPT = Path(__file__).parents[1] / "experiments" / "demo_values.py"
sys.path.insert(0, str(SCRIPT.parent))
from demo_values import discounted_returns  # noqa: E402


def test_discounted_returns_hold_the_last_reward_after_the_end():
    r = np.array([[1.0, 0.0, 2.0, 2.0]])
    out = discounted_returns(r, 0.5, tail=2)
    np.testing.assert_allclose(out[0, 3], 2.0 + 0.5 * 4.0)    # 2, then 2 / (1 - 0.5) held
    np.testing.assert_allclose(out[0, 0], 1.0 + 0.5 * (0.0 + 0.5 * (2.0 + 0.5 * out[0, 3])))


def test_the_table_reads_a_runs_checkpoint(tmp_path, two_clips, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    tr = Trainer(humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.25), tmp_path / "run", progress=False)
    try:
        tr.run(max_env_steps=8)
        ckpt = tr.save()
    finally:
        tr.close()
    out = subprocess.run([sys.executable, str(SCRIPT), str(ckpt), "--online-steps", "8"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert "1 demonstrations of 6 steps" in out, out
    rows = re.findall(r"^\| (\d+) \| ([-\d.]+) \| ([-\d.]+) \| ([-\d.]+) \|$", out, re.M)
    assert [int(r[0]) for r in rows] == [0, 1, 2, 3, 5], out  # five steps along a 6-step demonstration
    assert re.search(r"policy's own states \(8 env steps\): Q\(s, policy's a\) mean [-\d.]+", out), out
    missing = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "nowhere")], capture_output=True, text=True)
    assert missing.returncode != 0 and "nowhere: not a checkpoint directory" in missing.stderr
