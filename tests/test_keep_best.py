"""Evaluations during training: the humanoid's upright time (`train.eval_upright`), returns and goal success
(`train.eval_tasks`), and the checkpoint of the best evaluation (`train.keep_best`), which retention spares and a
resume remembers."""
import shutil

import numpy as np
import pytest
import torch

from conftest import toy_run_config
from fbcpr.inference.bfm import resolve_checkpoint
from fbcpr.core.checkpoint import CheckpointError, latest_checkpoint, load_checkpoint, read_trainer_meta
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import evaluate
from fbcpr.train.trainer import Trainer
from motions.library import MotionLibrary

torch.set_num_threads(1)


def toy_cfg(**train):
    return toy_run_config("td3", model={"hidden_dim": 16, "hidden_layers": 1},
                          agent={"reward": {"task": "reach-top-right"}},
                          train={"rollout_steps": 40, "updates_per_rollout": 1, "eval_every": 40,
                                 "keep_checkpoints": 1, "save_buffer": True, "keep_best": "eval/score", **train})


def scripted(values):
    """An evaluation hook that reports `values` in turn, one per evaluation."""
    it = iter(values)
    return lambda agent: {"score": next(it)}


def logged(run, key):
    rows = [line.split(",") for line in (run / "metrics.csv").read_text().splitlines()[1:]]
    return [(int(step), float(v)) for k, v, step in rows if k == key]


def best_of(run):
    folder = resolve_checkpoint(run / "checkpoints" / "best")
    return folder.name, read_trainer_meta(folder)["best"]


@pytest.mark.parametrize("mode, best_at", [("max", 1), ("min", 3)])
def test_best_checkpoint_is_the_best_evaluation_and_survives_retention(tmp_path, mode, best_at):
    values = [1.0, 3.0, 2.0, 0.5, 2.5]
    Trainer(toy_cfg(keep_best_mode=mode), tmp_path, evaluate=scripted(values), progress=False).run(max_env_steps=200)
    scores = logged(tmp_path, "eval/score")
    assert [v for _, v in scores] == values
    name, best = best_of(tmp_path)
    assert name == f"step_{scores[best_at][0]:010d}"
    assert best == {"metric": "eval/score", "mode": mode, "requires": {}, "value": values[best_at], "checkpoint": name}
    # keep_checkpoints: 1 removes every other checkpoint, the best one stays beside the latest
    kept = sorted(p.name for p in (tmp_path / "checkpoints").glob("step_*"))
    assert kept == sorted({name, (tmp_path / "checkpoints" / "latest").read_text()})
    assert make_agent(str(tmp_path / "checkpoints" / "best")).task == "reach-top-right"


def test_a_resume_remembers_the_best_value(tmp_path):
    Trainer(toy_cfg(), tmp_path / "a", evaluate=scripted([1.0, 3.0]), progress=False).run(max_env_steps=80)
    first, _ = best_of(tmp_path / "a")
    Trainer(toy_cfg(), tmp_path / "a", resume=True, evaluate=scripted([2.9]), progress=False).run(max_env_steps=40)
    assert best_of(tmp_path / "a")[0] == first  # 2.9 after the resume does not beat 3.0 from before it
    Trainer(toy_cfg(), tmp_path / "a", resume=True, evaluate=scripted([3.5]), progress=False).run(max_env_steps=40)
    name, best = best_of(tmp_path / "a")
    assert name != first and best["value"] == 3.5
    # the saved record is for another metric or direction: the resumed run starts a new one
    Trainer(toy_cfg(keep_best_mode="min"), tmp_path / "a", resume=True, evaluate=scripted([5.0]),
            progress=False).run(max_env_steps=40)
    name, best = best_of(tmp_path / "a")
    assert best["value"] == 5.0 and best["mode"] == "min"
    shutil.rmtree(tmp_path / "a" / "checkpoints" / name)  # a lost best folder is an error, not a silent fallback
    with pytest.raises(CheckpointError, match=name):
        make_agent(str(tmp_path / "a" / "checkpoints" / "best"))


def test_required_minimums_exclude_evaluations_from_the_best(tmp_path):
    # (score, stand) per evaluation: the highest scores come from evaluations that no longer stand
    evals = iter([(1.0, 10.0), (3.0, 2.0), (2.0, 10.0), (5.0, 9.9), (float("nan"), 10.0)])
    hook = lambda agent: dict(zip(("score", "stand"), next(evals)))
    cfg = toy_cfg(keep_best_requires={"eval/stand": 10})
    Trainer(cfg, tmp_path, evaluate=hook, progress=False).run(max_env_steps=200)
    name, best = best_of(tmp_path)
    assert name == f"step_{logged(tmp_path, 'eval/score')[2][0]:010d}"
    assert best == {"metric": "eval/score", "mode": "max", "requires": {"eval/stand": 10.0}, "value": 2.0,
                    "checkpoint": name}
    # a resume with other minimums starts a new record: 1.5 does not beat 2.0, but the record was for {stand: 10}
    Trainer(toy_cfg(keep_best_requires={"eval/stand": 5}), tmp_path, resume=True,
            evaluate=lambda agent: {"score": 1.5, "stand": 6.0}, progress=False).run(max_env_steps=40)
    assert best_of(tmp_path)[1]["value"] == 1.5


@pytest.mark.parametrize("algorithm", ["td3", "fb_cpr"])
def test_humanoid_runs_log_upright_seconds_and_keep_the_best(tmp_path, two_clips, algorithm):
    steps = 6  # short episodes: the measure covers a whole training episode when it is shorter than 10 s
    data = {
        "algorithm": algorithm,
        "agent": {"batch_size": 8, **({"reward": {"task": "move-ego-0-0"}} if algorithm == "td3" else {})},
        "env": {"name": "humanoid", "motions": str(two_clips), "max_episode_steps": steps},
        "train": {"num_envs": 2, "total_env_steps": 24, "warmup_steps": 4, "rollout_steps": 4,
                  "updates_per_rollout": 1, "buffer_capacity": 100, "priority_every": 0, "eval_every": 8,
                  "eval_upright": 2, "keep_best": "eval/upright_pushed_s", "checkpoint_every": 0,
                  "eval_tasks": ["move-ego-0-0", "t_pose"], "eval_episodes": 2,
                  "log_every": 4, "reward_buffer_size": 8, "torch_threads": 1},
    }
    if algorithm == "td3":
        data["model"] = {"hidden_dim": 16, "hidden_layers": 1}
    else:
        data["model"] = {"preset": "tiny"}
        data["agent"]["seq_length"] = 4
    Trainer(config_from_dict(data), tmp_path, progress=False).run()
    for key in ("eval/upright_s", "eval/upright_pushed_s"):
        values = [v for _, v in logged(tmp_path, key)]
        assert len(values) == 3 and all(0 < v <= steps / 30 for v in values), (key, values)
    got_up = [v for _, v in logged(tmp_path, "eval/got_up")]
    assert len(got_up) == 3 and all(v in (0.0, 0.5, 1.0) for v in got_up)  # a share of the 2 fall starts
    # a fresh start stands the 6 steps: the first evaluation is the best, and later ties do not replace it
    pushed = logged(tmp_path, "eval/upright_pushed_s")
    top = max(v for _, v in pushed)
    name, best = best_of(tmp_path)
    assert best["value"] == top and name == f"step_{next(s for s, v in pushed if v == top):010d}"
    # eval_tasks: returns and goal success at each evaluation, the numbers `fbcpr eval` gives the checkpoint
    returns, goals = dict(logged(tmp_path, "eval/return/move-ego-0-0")), dict(logged(tmp_path, "eval/goal/t_pose"))
    assert len(returns) == len(goals) == 3 and all(0 <= v <= steps for v in returns.values())
    assert all(0 <= v <= 1 for v in goals.values())
    assert dict(logged(tmp_path, "eval/goal_success")) == goals  # the mean over the one pose
    again = evaluate(make_agent(str(tmp_path / "checkpoints" / "best")), "all", tasks=["move-ego-0-0", "t_pose"],
                     episodes=2, motions=MotionLibrary.load(two_clips), steps=steps, seed=0, show_progress=False)
    step = int(name.removeprefix("step_"))
    assert again["reward"]["move-ego-0-0"]["return_mean"] == pytest.approx(returns[step], rel=1e-5)
    assert again["goal"]["t_pose"]["success"] == pytest.approx(goals[step])


def test_a_resume_follows_the_evaluation_period_of_its_new_config(tmp_path):
    Trainer(toy_cfg(eval_every=0, keep_best=""), tmp_path, progress=False).run(max_env_steps=80)
    Trainer(toy_cfg(), tmp_path, resume=True, evaluate=scripted([1.0, 2.0]), progress=False).run(max_env_steps=80)
    assert [s for s, _ in logged(tmp_path, "eval/score")] == [120, 160]  # switched on: from the next multiple
    assert best_of(tmp_path)[1]["value"] == 2.0
    # switched off again: no evaluation, and the run still ends (a period of 0 must not be stepped through)
    summary = Trainer(toy_cfg(eval_every=0, keep_best=""), tmp_path, resume=True, progress=False).run(max_env_steps=80)
    assert summary["env_steps"] == 240 and len(logged(tmp_path, "eval/score")) == 2


def test_eval_at_start_logs_the_loaded_model_at_step_zero_where_it_competes_for_best(tmp_path):
    Trainer(toy_cfg(), tmp_path / "base", evaluate=scripted([1.0]), progress=False).run(max_env_steps=40)
    run = Trainer(toy_cfg(eval_at_start=True), tmp_path / "c", evaluate=scripted([5.0, 2.0, 3.0]), progress=False,
                  init_from=tmp_path / "base")
    loaded = {k: v.clone() for k, v in run.agent.model.state_dict().items()}
    run.run(max_env_steps=80)
    assert logged(tmp_path / "c", "eval/score") == [(0, 5.0), (40, 2.0), (80, 3.0)]
    name, best = best_of(tmp_path / "c")
    assert name == "step_0000000000" and best["value"] == 5.0   # nothing beat the model it started from
    start = make_agent(str(tmp_path / "c" / "checkpoints" / "best")).model.state_dict()
    assert all(torch.equal(start[k], v) for k, v in loaded.items())
    # a resume goes on with the periodic evaluations only
    Trainer(toy_cfg(eval_at_start=True), tmp_path / "c", resume=True, evaluate=scripted([0.5]),
            progress=False).run(max_env_steps=40)
    assert logged(tmp_path / "c", "eval/score")[-1] == (120, 0.5) and len(logged(tmp_path / "c", "eval/score")) == 4


def test_the_start_evaluation_prompts_with_the_loaded_sample_and_needs_init_from(tmp_path):
    def fbcpr_cfg(**train):
        return config_from_dict({
            "model": {"preset": "tiny"}, "agent": {"batch_size": 32}, "env": {"name": "toy", "max_episode_steps": 30},
            "train": {"total_env_steps": 100_000, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                      "updates_per_rollout": 2, "buffer_capacity": 1000, "priority_every": 0, "eval_every": 0,
                      "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 60, "torch_threads": 1, **train}})

    base = Trainer(fbcpr_cfg(), tmp_path / "base", progress=False)
    base.run(max_env_steps=80)
    loaded = load_checkpoint(latest_checkpoint(tmp_path / "base" / "checkpoints")).reward_buffer()
    start = {"eval_every": 40, "eval_at_start": True, "keep_best": "eval/score"}
    with pytest.raises(ConfigError, match="train.eval_at_start: .*needs --init-from"):
        Trainer(fbcpr_cfg(**start), tmp_path / "fresh", evaluate=scripted([1.0]), progress=False)
    Trainer(fbcpr_cfg(**start), tmp_path / "c", evaluate=scripted([5.0, 1.0]), progress=False,
            init_from=tmp_path / "base").run(max_env_steps=40)
    best = load_checkpoint(resolve_checkpoint(tmp_path / "c" / "checkpoints" / "best"))
    assert best.path.name == "step_0000000000"
    for key in loaded:    # saved before any rollout: the model as loaded, prompted through its own sample
        np.testing.assert_array_equal(best.reward_buffer()[key], loaded[key])
