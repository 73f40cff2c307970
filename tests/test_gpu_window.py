"""The GPU window's one command, dry (device cpu, tiny sizes): every step runs, what comes back fits what a call
returns, and a second window on the same machine continues the first from its pack."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PART = 16 * 2**20


def window(out: Path, run: Path) -> str:
    env = {**os.environ, "OUT": str(out), "RUN": str(run), "PY": sys.executable, "WINDOW_S": "150",
           "OMP_NUM_THREADS": "1"}
    done = subprocess.run(["bash", "benchmarks/gpu_window.sh", "--dry-run"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=400)
    log = (out / "window.txt").read_text()
    assert done.returncode == 0, log + done.stderr[-2000:]
    return log


def test_gpu_window_dry_run_runs_every_step_and_continues_from_its_pack(tmp_path):
    run = tmp_path / "runs" / "window"
    log = window(tmp_path / "out1", run)
    assert "SELFTEST ok" in log
    assert any(line.startswith("RESULT engine device=cpu samples_per_s=") for line in log.splitlines()), log
    assert "starting from scratch" in log
    back = sorted((tmp_path / "out1").iterdir())
    assert len(back) <= 8 and sum(p.stat().st_size for p in back) < 64 * 2**20
    assert all(p.stat().st_size < PART for p in back)
    assert "metrics.csv" in {p.name for p in back} and any(".tar.part0-of-" in p.name for p in back)

    # a new machine keeps nothing (the runs dir and its pack are git-ignored): this one keeps the pack only
    shutil.rmtree(run)
    log = window(tmp_path / "out2", run)
    assert "continuing: the last window's run is gone, its pack is here" in log
    assert any(".tar.part0-of-" in p.name for p in (tmp_path / "out2").iterdir())
