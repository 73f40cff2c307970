"""The training engines: the async one (collectors in worker processes) trains end to end, keeps the config's
update-to-data ratio exactly as the sync loop does, checkpoints and resumes; configs it cannot run fail early."""
import numpy as np
import pytest
import torch
from conftest import toy_run_config

from fbcpr.core.checkpoint import load_checkpoint
from fbcpr.core.errors import ConfigError
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
    assert all(torch.equal(tr.collector.weights[k], v.cpu()) for k, v in tr.agent.model.state_dict().items())
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
