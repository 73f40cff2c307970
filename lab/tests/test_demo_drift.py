"""lab/experiments/demo_drift.py: demonstrations replayed open loop with noise, and agents from their first states."""
import subprocess
import sys
from pathlib import Path

import numpy as np

from motions.demonstrations import save_demonstration
from tests.test_demonstrations import planned  # noqa: F401 (a fixture)

SCRIPT = Path(__file__).parents[1] / "experiments" / "demo_drift.py"
sys.path.insert(0, str(SCRIPT.parent))
from demo_drift import noisy_replay, seconds_on_track  # noqa: E402


def test_seconds_on_track_count_until_the_pelvis_first_strays():
    ref = np.zeros((31, 2))
    h = ref.copy()
    h[15:, 0] = 0.2   # off track from step 15 (0.5 s at 30 Hz), back later does not count
    h[20:, 0] = 0.0
    h[:, 1] = 0.1     # within 0.15 m throughout: the whole 31 rows
    np.testing.assert_allclose(seconds_on_track(h, ref), [0.5, 31 / 30])


def test_a_noiseless_replay_retraces_the_demonstration_and_noise_leaves_it(planned):  # noqa: F811
    ref = planned.clip.qpos[1:, 2]   # after each step
    steps = len(planned.actions)
    exact = noisy_replay([planned, planned], 0.0, steps)[:, 0]
    np.testing.assert_allclose(exact, ref, atol=1e-3)
    noisy = noisy_replay([planned, planned], 0.5, steps, seed=1)
    assert np.abs(noisy[-1] - exact[-1]).max() > 1e-4  # the noise reaches the body
    assert not np.allclose(noisy[:, 0], noisy[:, 1])     # independent noise per demonstration


def test_the_script_prints_a_row_per_noise_and_agent(tmp_path, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "shoved.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path), "--noise", "0", "0.1"], capture_output=True,
                         text=True, check=True).stdout
    rows = [line for line in out.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert [r.split(" | ")[0] for r in rows] == ["| own actions, noise 0", "| own actions, noise 0.1", "| zero"]
    assert rows[0].split(" | ")[2].strip(" |") == f"{len(planned.actions) / 30:.2f}"  # on track throughout
