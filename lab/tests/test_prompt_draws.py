"""lab/experiments/prompt_draws.py: how far reward prompts of different state draws are apart, and from the pool."""
import subprocess
import sys
from pathlib import Path

from tests.conftest import tiny_humanoid_checkpoint

SCRIPT = Path(__file__).parents[1] / "experiments" / "prompt_draws.py"
TASKS = ["move-ego-0-0", "move-ego-0-2", "raisearms-l-l"]


def _rows(out: str) -> dict[str, list[float]]:
    rows = {}
    for line in out.splitlines():
        parts = line.split()
        if parts and parts[0] in TASKS:
            rows[parts[0]] = [float(x) for x in parts[1:]]
    return rows


def test_one_draw_repeated_agrees_with_itself_and_distinct_draws_do_not(tmp_path):
    model = tiny_humanoid_checkpoint(tmp_path, "model", seed=0)
    draws = [tiny_humanoid_checkpoint(tmp_path, f"d{i}", seed=i + 1) for i in range(4)]
    same = subprocess.run([sys.executable, str(SCRIPT), str(model), *[str(draws[0])] * 4, "--tasks", *TASKS],
                          capture_output=True, text=True, check=True).stdout
    rows = _rows(same)
    assert rows.keys() == set(TASKS)
    assert all(abs(v - 1.0) < 1e-3 for row in rows.values() for v in row)
    apart = subprocess.run([sys.executable, str(SCRIPT), str(model), *map(str, draws), "--tasks", *TASKS],
                           capture_output=True, text=True, check=True).stdout
    rows = _rows(apart)
    assert rows.keys() == set(TASKS)
    for mean, low, to_pool, halves in rows.values():
        assert -1 <= low <= mean < 0.999 and -1 <= halves <= 1
        assert to_pool > mean        # each draw is closer to the pool it is part of than to another draw
    assert "mean over 3 tasks" in apart


def test_fewer_than_four_draws_is_refused(tmp_path):
    model = tiny_humanoid_checkpoint(tmp_path, "model", seed=0)
    res = subprocess.run([sys.executable, str(SCRIPT), str(model), str(model), str(model)],
                         capture_output=True, text=True)
    assert res.returncode != 0 and "at least 4 draws" in res.stderr
