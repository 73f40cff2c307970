"""lab/experiments/label_generalisation.py: a behaviour-cloning fit on some demonstration folders, scored on others
beside the constant that predicts the training targets' mean."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from motions.demonstrations import Demonstration, save_demonstration
from tests.test_demonstrations import planned  # noqa: F401 (a fixture)

SCRIPT = Path(__file__).parents[1] / "experiments" / "label_generalisation.py"


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=300)


def test_the_fit_learns_its_rows_and_is_scored_beside_the_constant(tmp_path, planned):  # noqa: F811
    labels = np.random.default_rng(0).uniform(-0.8, 0.8, planned.actions.shape).astype(np.float32)
    save_demonstration(Demonstration(planned.clip, planned.actions, planned.action_mapping, labels),
                       tmp_path / "train" / "shoved.npz")
    save_demonstration(Demonstration(planned.clip, planned.actions, planned.action_mapping, -labels),
                       tmp_path / "test" / "shoved.npz")
    out = run("--train", str(tmp_path / "train"), "--test", str(tmp_path / "test"), "--steps", "300")
    assert out.returncode == 0, out.stderr
    table = {m[1]: (m[2], int(m[3]), float(m[4]), float(m[5]))
             for m in re.finditer(r"\| (\S+) \| (train|held out) \| (\d+) \| ([\d.]+) \| ([\d.]+) \|", out.stdout)}
    role, n, fit, const = table[str(tmp_path / "train")]
    assert (role, n) == ("train", 6) and fit < 0.2 * const        # it learnt its own rows
    role, n, fit, const = table[str(tmp_path / "test")]
    # the held-out labels are the training ones negated: the fit, which learnt those, is further off than the mean
    assert (role, n) == ("held out", 6) and fit > const
    expected = np.square(labels.mean(0) + labels).mean()
    assert const == float(f"{expected:.3f}")


def test_a_bad_folder_is_named(tmp_path, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "train" / "shoved.npz")
    out = run("--train", str(tmp_path / "train"), "--test", str(tmp_path / "missing"))
    assert out.returncode != 0 and "missing" in out.stderr and "Traceback" not in out.stderr
    out = run("--train", str(tmp_path / "train"), "--test", str(tmp_path / "train"), "--steps", "0")
    assert out.returncode != 0 and "--steps" in out.stderr
