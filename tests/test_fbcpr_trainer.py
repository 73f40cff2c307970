"""Online trainer on the toy env: exact resume, clean stop on signals, buffer, CLI."""
import os
import re
import shutil
import signal
import threading

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from fbcpr.train.buffer import ReplayBuffer, transition_specs
from fbcpr.core.checkpoint import load_checkpoint, save_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.core.schema import dump_config
from fbcpr.envs import toy as pm
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)


def tiny_cfg(**train):
    return config_from_dict({
        "model": {"preset": "tiny"},
        "agent": {"batch_size": 32},
        "env": {"name": "toy", "max_episode_steps": 30},
        "train": {"total_env_steps": 100_000, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                  "updates_per_rollout": 2, "buffer_capacity": 1000, "z_update_every": 7, "priority_every": 100,
                  "eval_every": 0, "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 50,
                  "save_buffer": True, "torch_threads": 1, **train},
    })


def state_of(tr):
    sd = {f"m.{k}": v.clone() for k, v in tr.agent.model.state_dict().items()}
    sd.update({f"t.{k}": v.clone() for k, v in tr.agent.targets.state_dict().items()})
    for name, opt in tr.agent.optimizers.items():
        for i, st in opt.state_dict()["state"].items():
            sd.update({f"o.{name}.{i}.{k}": torch.as_tensor(v).clone() for k, v in st.items()})
    return sd


def test_resume_reproduces_training_bit_for_bit(tmp_path):
    a = Trainer(tiny_cfg(), tmp_path / "a", progress=False)
    a.run(max_env_steps=120)                       # warm-up, updates and a priority refresh, then a checkpoint
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    a.run(max_env_steps=80)
    b = Trainer(tiny_cfg(), tmp_path / "b", resume=True, progress=False)
    assert b.env_steps == 120 and b.learner.updates == a.learner.updates - 8
    b.run(max_env_steps=80)
    sa, sb = state_of(a), state_of(b)
    assert sa.keys() == sb.keys()
    diff = [k for k in sa if not torch.equal(sa[k], sb[k])]
    assert not diff, diff[:5]
    assert (a.env_steps, a.learner.updates) == (b.env_steps, b.learner.updates)
    np.testing.assert_array_equal(a.buffer.data["next_obs"], b.buffer.data["next_obs"])
    # a fresh run (no resume) diverges from it, so the comparison above is not vacuous
    c = Trainer(tiny_cfg(seed=1), tmp_path / "c", progress=False)
    c.run(max_env_steps=200)
    assert any(not torch.equal(sa[k], v) for k, v in state_of(c).items())


def test_checkpoint_contents_and_reward_buffer(tmp_path):
    tr = Trainer(tiny_cfg(save_buffer=False), tmp_path, progress=False)
    summary = tr.run(max_env_steps=80)
    ck = load_checkpoint(summary["checkpoint"])
    rb = ck.reward_buffer()
    assert rb["next_obs"].shape == (50, pm.OBS_DIM) and rb["qpos"].shape == (50, pm.NQ)
    np.testing.assert_allclose(rb["next_obs"], rb["qpos"], atol=1e-6)  # qpos is that of s'
    assert not ck.has("replay_buffer.safetensors")
    assert (tmp_path / "metrics.csv").exists() and any((tmp_path / "tb").iterdir())
    assert ck.model_config.obs_dim == pm.OBS_DIM


def test_sigint_writes_final_checkpoint(tmp_path, default_sigint):
    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    summary = tr.run()
    timer.join()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored
    assert summary["interrupted"] and 0 < summary["env_steps"] < 100_000
    ck = load_checkpoint(summary["checkpoint"])
    assert ck.trainer_state()[1]["env_steps"] == summary["env_steps"]


def test_replay_buffer_ring_and_memmap(tmp_path):
    specs = transition_specs(4, 2, 3, 2, 2)
    for mm in (None, tmp_path / "mm"):
        buf = ReplayBuffer(5, specs, memmap_dir=mm)
        for i in range(3):
            k = 3
            batch = {f: np.full((k, *s), 10 * i + np.arange(k).reshape(-1, *([1] * len(s))), np.float32)
                     for f, s in specs.items()}
            buf.add(batch)
        assert len(buf) == 5 and buf.pos == 4
        assert set(buf.data["obs"][:, 0].tolist()) == {11, 12, 20, 21, 22}
        s = buf.sample(np.random.default_rng(0), 64)
        assert s["z"].shape == (64, 3) and s["z"].dtype == torch.float32
        assert buf.reward_inference_sample(100)["qpos"].shape == (5, 2)
        sub = buf.reward_inference_sample(3, np.random.default_rng(1))
        assert sub["next_obs"].shape == (3, 4) and len(np.unique(sub["next_obs"][:, 0])) == 3  # distinct rows
        with pytest.raises(ValueError, match="field 'action'"):
            buf.add({**batch, "action": np.zeros((3, 5))})
    assert (tmp_path / "mm" / "obs.npy").exists()


def test_toy_env_api_and_feasible_demos():
    env = pm.PointMassVectorEnv(3, max_episode_steps=2)
    obs, info = env.reset(seed=0)
    assert obs.shape == (3, 2) and info["qpos"].shape == (3, 2)
    obs1, r, term, trunc, info = env.step(np.ones((3, 2)))
    assert not trunc.any()
    obs2, r, term, trunc, info = env.step(np.ones((3, 2)))
    assert trunc.all() and info["_final_obs"].all()
    np.testing.assert_allclose(info["final_obs"], np.minimum(obs1 + 0.1, 1.0), atol=1e-6)
    np.testing.assert_allclose(info["final_qvel"], info["final_obs"] - obs1, atol=1e-6)
    for name, demo in pm.demo_paths().items():
        a = np.diff(demo.astype(np.float64), axis=0) / pm.STEP   # the action that realises each demo step
        assert np.abs(a).max() <= 1.0 and np.abs(demo).max() <= 1.0, name
    with pytest.raises(ValueError, match="actions must have shape"):
        env.step(np.ones((2, 2)))


def test_cli_train_and_bad_config(tmp_path):
    from fbcpr.cli.app import app

    cfg_path = tmp_path / "tiny.yaml"
    cfg_path.write_text(dump_config(tiny_cfg(total_env_steps=60, save_buffer=False)))
    runner = CliRunner()
    res = runner.invoke(app, ["train", str(cfg_path), "--out", str(tmp_path / "run"), "--no-progress"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "run" / "checkpoints" / "latest").exists()
    res = runner.invoke(app, ["train", str(cfg_path), "--out", str(tmp_path / "run"), "--no-progress"])
    assert res.exit_code == 1 and "--resume" in res.output
    bad = tmp_path / "bad.yaml"
    bad.write_text("agent:\n  relabel_prob: 2\n")
    res = runner.invoke(app, ["train", str(bad), "--out", str(tmp_path / "run2")])
    assert res.exit_code == 1 and "agent.relabel_prob" in res.output


def test_failure_signatures_are_logged_once(tmp_path):
    tr = Trainer(tiny_cfg(), tmp_path / "run", progress=False)
    tr.collector.stats[:] = (950.0, 900.0, 1000.0)
    row = {"disc_expert": 0.99, "disc_online": 0.01, **tr._take_action_stats()}
    assert row["action_abs"] == pytest.approx(0.95) and row["action_saturated"] == pytest.approx(0.9)
    tr._warn(row)
    tr._warn(row)
    lines = (tmp_path / "run" / "warnings.txt").read_text().splitlines()
    assert [line.split("\t")[1] for line in lines] == ["discriminator", "bang-bang"]
    tr._warn({"disc_expert": 0.6, "disc_online": 0.4, "action_saturated": 0.1})
    assert len((tmp_path / "run" / "warnings.txt").read_text().splitlines()) == 2
    assert tr._take_action_stats() == {}


# ------------------------------------------------------------------------ issue 15: resume, signals, progress


def tree(root):
    """{relative path: (size, mtime_ns)} of every file under root: what a no-op must leave untouched."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


def test_resume_without_replay_buffer_keeps_the_reward_sample(tmp_path, capsys):
    cfg = dict(save_buffer=False, reward_buffer_size=300)
    first = Trainer(tiny_cfg(**cfg), tmp_path, progress=False).run(max_env_steps=160)
    before = load_checkpoint(first["checkpoint"]).reward_buffer()
    assert len(before["next_obs"]) == 160
    tr = Trainer(tiny_cfg(**cfg), tmp_path, resume=True, progress=False)
    assert "no replay buffer" in capsys.readouterr().err  # said at resume, loudly
    after = load_checkpoint(tr.run(max_env_steps=40)["checkpoint"]).reward_buffer()
    assert len(after["next_obs"]) == 200                   # 160 carried + 40 new, not just the 40 new
    carried = {r.tobytes() for r in before["next_obs"]}
    assert sum(r.tobytes() in carried for r in after["next_obs"]) == 160
    again = Trainer(tiny_cfg(**cfg), tmp_path, resume=True, progress=False)  # and once more: it keeps adding up
    final = load_checkpoint(again.run(max_env_steps=200)["checkpoint"]).reward_buffer()
    assert len(final["next_obs"]) == 300
    for buf in (after, final):  # a subsampled carry keeps each row one transition (the toy observes obs = qpos)
        np.testing.assert_array_equal(buf["next_obs"], buf["qpos"])


def test_resume_drops_a_reward_sample_whose_rows_mix_transitions(tmp_path, capsys):
    cfg = dict(save_buffer=False, reward_buffer_size=300)
    path = Trainer(tiny_cfg(**cfg), tmp_path, progress=False).run(max_env_steps=160)["checkpoint"]
    ckpt = load_checkpoint(path)
    mixed = ckpt.reward_buffer()
    mixed["qpos"] = np.roll(mixed["qpos"], 1, axis=0)  # as resumes before the fix saved them
    save_checkpoint(path, ckpt.model, ckpt.config, trainer_state=ckpt.trainer_state(), reward_buffer=mixed)
    tr = Trainer(tiny_cfg(**cfg), tmp_path, resume=True, progress=False)
    assert "reward-inference sample is dropped" in capsys.readouterr().err
    after = load_checkpoint(tr.run(max_env_steps=40)["checkpoint"]).reward_buffer()
    assert len(after["next_obs"]) == 40  # the new transitions only
    np.testing.assert_array_equal(after["next_obs"], after["qpos"])


def test_resume_without_replay_buffer_refills_before_updating(tmp_path):
    cfg = dict(save_buffer=False, warmup_steps=80, updates_per_rollout=3)
    first = Trainer(tiny_cfg(**cfg), tmp_path, progress=False).run(max_env_steps=160)
    done = first["updates"]
    assert done > 0
    tr = Trainer(tiny_cfg(**cfg), tmp_path, resume=True, progress=False)
    assert tr.run(max_env_steps=60)["updates"] == done          # the empty buffer refills from the loaded policy
    assert len(tr.buffer) == 60
    tr = Trainer(tiny_cfg(**cfg), tmp_path, resume=True, progress=False)  # stopped mid-refill: refill again
    assert tr.run(max_env_steps=80)["updates"] == done + 3       # updates once 80 new env steps are in
    with_buffer = Trainer(tiny_cfg(warmup_steps=80, updates_per_rollout=3), tmp_path / "kept", progress=False)
    kept = with_buffer.run(max_env_steps=160)["updates"]
    again = Trainer(tiny_cfg(warmup_steps=80, updates_per_rollout=3), tmp_path / "kept", resume=True, progress=False)
    assert again.run(max_env_steps=20)["updates"] == kept + 3    # a saved buffer needs no refill


def test_noop_resume_changes_nothing_on_disk_and_more_steps_continue(tmp_path):
    from fbcpr.cli.app import app

    cfg_path = tmp_path / "tiny.yaml"
    cfg_path.write_text(dump_config(tiny_cfg(total_env_steps=80, save_buffer=False)))
    run = tmp_path / "run"
    runner = CliRunner()
    first = runner.invoke(app, ["train", str(cfg_path), "--out", str(run), "--no-progress"])
    assert first.exit_code == 0, first.output
    updates_before = int(re.search(r"([\d,]+) updates", first.output).group(1))
    snapshot = tree(run)
    res = runner.invoke(app, ["train", str(cfg_path), "--out", str(run), "--resume", "--steps", "40", "--no-progress"])
    assert res.exit_code == 0 and "nothing to do" in res.output, res.output
    assert tree(run) == snapshot
    res = runner.invoke(app, ["train", str(cfg_path), "--out", str(run), "--resume", "--more-steps", "40",
                              "--no-progress"])
    # no replay buffer in the checkpoint: 40 env steps refill it (said up front), then 40 of learning, as many
    # updates as the first run made in its 40 env steps after its 40 of warm-up
    assert res.exit_code == 0 and "finished at 160 env steps" in res.output, res.output
    said = " ".join(res.output.split())
    assert "refills an empty buffer for 40 env steps" in said and "then 40 env steps of learning" in said
    assert said.index("refills") < said.index("finished")
    assert int(re.search(r"([\d,]+) updates", res.output).group(1)) == 2 * updates_before > 0
    res = runner.invoke(app, ["train", str(cfg_path), "--out", str(tmp_path / "new"), "--more-steps", "40"])
    assert res.exit_code != 0 and "--resume" in res.output
    # the API side: a run with nothing to do does not rewrite its checkpoint
    ckpt = run / "checkpoints" / (run / "checkpoints" / "latest").read_text()
    mtime = (ckpt / "manifest.json").stat().st_mtime_ns
    tr = Trainer(tiny_cfg(total_env_steps=80, save_buffer=False), run, resume=True, progress=False)
    assert tr.run()["env_steps"] == 160 and (ckpt / "manifest.json").stat().st_mtime_ns == mtime


def test_sighup_stops_like_sigint(tmp_path):
    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGHUP))
    timer.start()
    summary = tr.run()
    timer.join()
    assert summary["interrupted"] and load_checkpoint(summary["checkpoint"]).trainer_state()[1]["env_steps"] > 0


def test_first_signal_says_stopping_second_aborts(tmp_path, capfd):
    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    old = tr._install_signals()
    try:
        os.kill(os.getpid(), signal.SIGINT)
        assert tr._stop and "stopping" in capfd.readouterr().err
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def test_stop_interrupts_the_tracking_pass_within_a_step(tmp_path):
    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    steps = []
    make = tr.bundle.make_eval_env

    def counting(n, horizon):
        env = make(n, horizon)
        step = env.step

        def counted(action):
            steps.append(1)
            if len(steps) == 3:
                tr._stop = True           # a Ctrl-C arrives during the tracking rollout
            return step(action)
        env.step = counted
        return env

    tr.bundle.make_eval_env = counting
    priorities = np.array(tr.bundle.library.priorities, copy=True)
    assert tr.evaluate(refresh_priorities=True) == {}
    assert len(steps) == 3                  # not the whole 30-step episode
    np.testing.assert_array_equal(tr.bundle.library.priorities, priorities)


def test_progress_bar_keeps_steps_rate_and_eta_at_80_columns():
    import io

    from rich.console import Console
    from rich.progress import Progress

    from fbcpr.train.reporting import progress_columns

    con = Console(width=80, file=io.StringIO())
    bar = Progress(*progress_columns(), console=con, expand=True)
    bar.add_task("training", total=1_000_000, completed=12_345,
                 metrics="u 1,234 fb 3.1 act -12 crit 0.41 disc 1.3 r 0.02 " * 3)
    con.print(bar.get_renderable())
    lines = con.file.getvalue().splitlines()
    assert len(lines) == 1 and len(lines[0]) <= 80
    assert "12,345/1,000,000" in lines[0] and "/s" in lines[0] and "eta -:--:--" in lines[0]


def test_no_progress_prints_plain_log_lines(tmp_path, capsys):
    Trainer(tiny_cfg(log_every=40), tmp_path, progress=False).run(max_env_steps=120)
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if "steps/s" in line]
    assert len(lines) >= 2 and lines[-1].startswith("120/120 steps (100.0%)") and "eta" in lines[-1]
    assert "steps/s" not in out  # stdout stays the caller's


def test_cuda_without_cuda_leaves_no_run_directory(tmp_path):
    from fbcpr.cli.app import app

    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    cfg_path = tmp_path / "tiny.yaml"
    cfg_path.write_text(dump_config(tiny_cfg(total_env_steps=60)))
    res = CliRunner().invoke(app, ["train", str(cfg_path), "--out", str(tmp_path / "run"), "--device", "cuda"])
    assert res.exit_code == 1 and "CUDA" in res.output
    assert not (tmp_path / "run").exists()
    with pytest.raises(Exception, match="CUDA"):
        Trainer(tiny_cfg(device="cuda"), tmp_path / "run2", progress=False)
    assert not (tmp_path / "run2").exists()


def test_retention_keeps_the_last_k_and_every_nth(tmp_path):
    from fbcpr.core.checkpoint import prunable_checkpoints

    for step in range(0, 1000, 100):
        (tmp_path / f"step_{step:010d}").mkdir()
    names = [p.name for p in prunable_checkpoints(tmp_path, keep_last=3, keep_every=500)]
    assert names == [f"step_{s:010d}" for s in (100, 200, 300, 400, 600)]
    assert len(prunable_checkpoints(tmp_path, keep_last=3, keep_every=0)) == 7


def test_memmapped_buffer_is_removed_when_training_ends(tmp_path):
    from fbcpr.train.trainer import train

    train(tiny_cfg(total_env_steps=60, buffer_memmap_mb=0.0), tmp_path, progress=False)
    assert not (tmp_path / "buffer_mmap").exists() and (tmp_path / "checkpoints" / "latest").exists()


def test_a_deadline_is_kept_to_within_a_step(tmp_path):
    import time

    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    tr.run(max_env_steps=60)                      # imports and first-call costs out of the way
    t0 = time.monotonic()
    summary = tr.run(deadline=t0 + 1.0)
    took = time.monotonic() - t0
    assert not summary["interrupted"] and summary["env_steps"] > 60
    assert took < 1.0 * 1.15 + 0.3, took           # the budget plus the final checkpoint, not whole chunks


def test_wall_clock_of_training_adds_up_over_resumes(tmp_path):
    import time

    from fbcpr.core.checkpoint import latest_checkpoint, read_trainer_meta

    def wall(run):
        rows = [line.split(",") for line in (run / "metrics.csv").read_text().splitlines()[1:]]
        return [float(v) for k, v, _ in rows if k == "wall_s"]

    tr = Trainer(tiny_cfg(), tmp_path, progress=False)
    tr.run(max_env_steps=80)
    first = wall(tmp_path)
    saved = read_trainer_meta(latest_checkpoint(tmp_path / "checkpoints"))["wall_s"]
    assert len(first) >= 2 and 0 < first[0] and all(np.diff(first) > 0) and first[-1] <= saved
    time.sleep(0.5)  # time between sessions is not training time
    took = Trainer(tiny_cfg(), tmp_path, resume=True, progress=False).run(max_env_steps=40)["seconds"]
    later = wall(tmp_path)[len(first):]
    assert later and saved < later[0] and later[-1] <= saved + took


@pytest.mark.parametrize("env_threads, want", [(0, None), (3, 3)])
def test_env_threads_reach_the_env(tmp_path, monkeypatch, env_threads, want):
    """train.env_threads caps the training envs' physics threads (runs sharing a machine); 0 keeps all cores."""
    import fbcpr.train.trainer as trainer_mod

    seen = []
    real = trainer_mod.make_env

    def spy(cfg, num_envs, seed, threads=None):
        seen.append(threads)
        return real(cfg, num_envs, seed, threads)

    monkeypatch.setattr(trainer_mod, "make_env", spy)
    Trainer(tiny_cfg(env_threads=env_threads), tmp_path, progress=False)
    assert seen == [want]


def test_bf16_auto_says_which_precision_it_chose(tmp_path, monkeypatch):
    from dataclasses import replace

    from fbcpr.nn import precision

    for bf16_time, chosen in ((0.2, "bf16"), (5.0, "float32")):
        monkeypatch.setattr(precision, "matmul_seconds", lambda dtype, device: bf16_time if dtype == torch.bfloat16 else 1.0)
        cfg = tiny_cfg()
        tr = Trainer(replace(cfg, agent=replace(cfg.agent, bf16="auto")), tmp_path / chosen, progress=False)
        assert tr.agent.bf16 is (chosen == "bf16")
        assert f"agent.bf16: auto chose {chosen} on cpu" in (tmp_path / chosen / "warnings.txt").read_text()
    Trainer(tiny_cfg(), tmp_path / "fixed", progress=False)   # a fixed setting needs no word
    assert not (tmp_path / "fixed" / "warnings.txt").exists()


def test_ranks_take_bf16_only_where_every_rank_chose_it():
    from fbcpr.nn.distributed import Replicas
    from fbcpr.train.trainer import agree_on_bf16

    two = Replicas(rank=0, world_size=2)
    for other, mine, agreed in ((1.0, True, True), (0.0, True, False), (1.0, False, False)):
        two.sum = lambda values, other=other: values + other   # the other rank's choice, as all_reduce adds it
        assert agree_on_bf16(mine, two) is agreed
    assert agree_on_bf16(True, Replicas()) is True and agree_on_bf16(False, Replicas()) is False   # one process


def test_cuda_graph_on_the_cpu_is_said_to_be_ignored(tmp_path):
    from dataclasses import replace

    cfg = tiny_cfg()
    tr = Trainer(replace(cfg, agent=replace(cfg.agent, cuda_graph=True)), tmp_path / "run", progress=False)
    assert not tr.agent.graphed
    assert "agent.cuda_graph: ignored on cpu" in (tmp_path / "run" / "warnings.txt").read_text()


def test_a_log_gets_whole_plain_lines_not_a_cut_bar(tmp_path, capsys):
    """With the bar asked for but stderr not a terminal (a log, CI), training prints the plain progress lines, with
    every metric, instead of the bar's last state cut to 80 columns."""
    tr = Trainer(tiny_cfg(total_env_steps=80), tmp_path, progress=True)
    assert not tr.progress_enabled
    tr.run()
    out, err = capsys.readouterr()
    lines = [line for line in err.splitlines() if "steps/s" in line]
    assert lines and lines[-1].startswith("80/80 steps (100.0%)") and "| u " in lines[-1]
    assert "…" not in out + err and "━" not in err


def test_steps_round_up_to_whole_phases_with_a_message(tmp_path):
    from fbcpr.cli.app import app

    cfg_path = tmp_path / "tiny.yaml"
    cfg_path.write_text(dump_config(tiny_cfg(warmup_steps=100)))  # phases of 20 env steps (rollout_steps: 20)
    res = CliRunner().invoke(app, ["train", str(cfg_path), "--out", str(tmp_path / "r"), "--steps", "10"])
    said = " ".join(res.output.split())
    assert res.exit_code == 0, res.output
    assert "10 env steps rounded up to 20" in said and "the run ends at 20" in said
    assert "finished at 20 env steps" in said and "20/10" not in said
