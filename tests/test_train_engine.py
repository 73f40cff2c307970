"""The training engines: the async one (collectors in worker processes) trains end to end, keeps the config's
update-to-data ratio exactly as the sync loop does, checkpoints and resumes; configs it cannot run fail early."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import toy_run_config

from fbcpr.core.checkpoint import load_checkpoint
from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import dump_config
from fbcpr.train.trainer import Trainer
from fbcpr.train.workers import CollectorPool

torch.set_num_threads(1)


def test_async_engine_trains_at_the_configs_ratio_and_resumes(tmp_path):
    async_cfg = toy_run_config(train={"engine": "async", "collectors": 2, "total_env_steps": 200, "save_buffer": True,
                                      "z_update_every": 7})
    sync = Trainer(toy_run_config(train={"total_env_steps": 200}), tmp_path / "sync", progress=False)
    sync.run(max_env_steps=120)
    sync.close()
    tr = Trainer(async_cfg, tmp_path / "async", progress=False)
    assert isinstance(tr.collector, CollectorPool)
    before = {k: v.clone() for k, v in tr.agent.model.state_dict().items()}
    summary = tr.run(max_env_steps=120)
    # warm-up 40 steps, then 2 updates per 20-step phase: the sync loop's count, whatever the collectors' speed
    assert (summary["env_steps"], summary["updates"]) == (sync.env_steps, sync.learner.updates) == (120, 10)
    assert len(tr.buffer) == 120 and tr.collector.episodes > 0  # 30-step episodes: some ended
    # both collectors wrote their envs: the latents of an env change every 7 steps, the 4 envs differ
    assert len(np.unique(tr.buffer.data["z"][:120].round(5), axis=0)) > 4
    # the policy that collects is the learner's: its weights were handed over after the updates
    assert any(not torch.equal(before[k], v) for k, v in tr.agent.model.state_dict().items())
    model = tr.agent.model.state_dict()
    assert all(torch.equal(tr.collector.weights[k], model[k].cpu()) for k in tr.collector.weights)
    # only what acting reads travels: the normaliser, the actor and B, not the critics or the discriminator
    assert {k.split(".")[0] for k in tr.collector.weights} == {"obs_normalizer", "actor", "backward_map"}
    tr.close()
    assert not tr.collector.procs

    ckpt = load_checkpoint(summary["checkpoint"])
    assert "env_qpos" not in ckpt.trainer_state()[0]  # the collectors' envs are not saved
    again = Trainer(async_cfg, tmp_path / "async", resume=True, progress=False)
    assert (again.env_steps, again.learner.updates, len(again.buffer)) == (120, 10, 120)
    summary = again.run()
    assert (summary["env_steps"], summary["updates"]) == (200, 18)
    again.close()
    # the sync engine resumes an async checkpoint too, with new episodes
    back = Trainer(toy_run_config(train={"total_env_steps": 240, "save_buffer": True}), tmp_path / "async",
                   resume=True, progress=False)
    assert back.run()["updates"] == 22
    back.close()


def test_async_engine_refuses_what_it_cannot_run(tmp_path):
    with pytest.raises(ConfigError, match="train.collectors"):
        Trainer(toy_run_config(train={"engine": "async", "collectors": 3}), tmp_path / "a", progress=False)
    with pytest.raises(ConfigError, match="train.engine"):
        toy_run_config(train={"engine": "threads"})


def test_a_stop_signal_to_the_whole_process_group_ends_an_async_run_with_a_checkpoint(tmp_path):
    """Ctrl-C or `timeout` signal every process of the group: the collectors leave it to the trainer, which stops
    at its next safe point with a final checkpoint, then stops them."""
    cfg = toy_run_config(train={"engine": "async", "collectors": 2, "total_env_steps": 10**7})
    (tmp_path / "cfg.yaml").write_text(dump_config(cfg))
    run = tmp_path / "run"
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "fbcpr", "train", str(tmp_path / "cfg.yaml"), "--out", str(run),
                             "--no-progress"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while not ((run / "metrics.csv").exists() and "updates" in (run / "metrics.csv").read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, err
    assert "stopping" in err and "interrupted at" in out, out + err
    latest = run / "checkpoints" / (run / "checkpoints" / "latest").read_text().strip()
    meta = load_checkpoint(latest).trainer_state()[1]
    assert meta["env_steps"] >= 40 and meta["updates"] > 0
