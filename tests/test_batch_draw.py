"""benchmarks/batch_draw.py: the rows the lease call reads (its grep for the `device` row decides host or device draws)."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from motions.clip import from_qpos, save_clip

SCRIPT = Path(__file__).parents[1] / "benchmarks" / "batch_draw.py"


def test_prints_update_only_device_and_host_rows_in_the_format_the_lease_call_greps(tmp_path):
    rng = np.random.default_rng(0)
    for i, n in enumerate((30, 40)):
        qpos = np.zeros((n, 76))
        qpos[:, 2], qpos[:, 3] = 0.9, 1.0
        qpos[:, 7:] = np.cumsum(rng.normal(0, 0.01, (n, 69)), 0)
        save_clip(from_qpos(qpos, f"c{i}"), tmp_path / f"c{i}.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "--sizes", "tiny", "--rows", "600", "--updates", "2",
                          "--reps", "1", "--threads", "1", "--motions", str(tmp_path), "--cpu"],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    rows = {m.group(1): float(m.group(2)) for m in
            re.finditer(r"^tiny +256 +eager +(update only|device|host) +(?:[\d.]+ +)?([\d.]+) +[\d.]+$", out, re.M)}
    assert set(rows) == {"update only", "device", "host"}, out
    assert all(v > 0 for v in rows.values())
    assert re.search(r"^tiny +256 +eager +device ", out, re.M)      # the lease call's grep, with small for tiny
