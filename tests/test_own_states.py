"""A model's reward states from its own rollouts (fbcpr/configs/own-states.yaml): a warm start whose warm-up outlasts the
run rolls the loaded policy out, makes no update, and saves a reward sample of those rollouts' states."""
from pathlib import Path

import numpy as np
import torch

from conftest import toy_run_config
from fbcpr.core.checkpoint import latest_checkpoint, load_checkpoint
from fbcpr.core.config import load_config
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)
CONFIGS = Path(__file__).resolve().parents[1] / "fbcpr" / "configs"


def toy(**train):
    return toy_run_config(model={"actor_std": 0.05}, train={"reward_buffer_size": 60, **train})


def test_a_warm_up_past_the_end_rolls_the_loaded_policy_out_and_samples_its_states(tmp_path):
    Trainer(toy(), tmp_path / "base", progress=False).run(max_env_steps=200)
    base = load_checkpoint(latest_checkpoint(tmp_path / "base" / "checkpoints"))
    run = Trainer(toy(total_env_steps=120, warmup_steps=1_000, save_buffer=True), tmp_path / "own", progress=False,
                  init_from=base.path)
    summary = run.run()
    assert summary["updates"] == 0 and summary["env_steps"] == 120
    own = load_checkpoint(latest_checkpoint(tmp_path / "own" / "checkpoints"))
    weights, loaded = own.model.state_dict(), base.model.state_dict()
    assert all(torch.equal(weights[k], loaded[k]) for k in loaded)          # no update moved them
    # the loaded policy acted (its mean plus the 0.05 exploration noise), not the uniform warm-up of a fresh run
    rows = run.buffer.data
    obs, z, action = (torch.as_tensor(np.asarray(rows[k][:120])) for k in ("obs", "z", "action"))
    mean = base.model.act(obs, z, mean=True)
    assert (action - mean).abs().max() < 0.3
    # every state of the saved sample is one of these rollouts', none of the base's own sample
    sample, theirs = own.reward_buffer()["next_obs"], base.reward_buffer()["next_obs"]
    assert len(sample) == 60
    rolled = {tuple(r) for r in np.asarray(rows["next_obs"][:120]).tolist()}
    assert all(tuple(r) in rolled for r in sample.tolist())
    assert not {tuple(r) for r in theirs.tolist()} & {tuple(r) for r in sample.tolist()}


def test_the_shipped_recipe_makes_no_update():
    cfg = load_config(CONFIGS / "own-states.yaml")
    assert cfg.train.warmup_steps > cfg.train.total_env_steps
    assert cfg.train.reward_buffer_size <= cfg.train.total_env_steps <= cfg.train.buffer_capacity
