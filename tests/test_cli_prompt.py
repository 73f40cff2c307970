"""`fbcpr prompt`, `fbcpr track`, `fbcpr timeline` end to end on a tiny checkpoint made here."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import humanoid_states
from fbcpr.inference.bfm import BFM
from fbcpr.core.checkpoint import save_checkpoint
from fbcpr.cli.app import app
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel
from humanoid_env.model import load_model
from humanoid_env.render import renderer_available
from motions.clip import from_qpos, save_clip

torch.set_num_threads(1)
HAS_RENDERER = renderer_available()


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    buf = humanoid_states(64, seed=0, drop=(-0.8, 0.5))
    model = FBCPRModel(cfg.model)
    model.obs_normalizer.update(torch.as_tensor(buf["next_obs"]))
    return save_checkpoint(tmp_path_factory.mktemp("cli") / "tiny", model, cfg, reward_buffer=buf)


@pytest.fixture(scope="module")
def clip_path(tmp_path_factory) -> Path:
    qpos = np.tile(load_model().qpos0, (8, 1))
    qpos[:, 7 + 45] = np.linspace(0.0, 0.8, 8)
    return save_clip(from_qpos(qpos, name="arm_swing"), tmp_path_factory.mktemp("clips") / "arm_swing.npz")


def run(*args: str):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_prompt_reward_prints_return(ckpt, tmp_path):
    video = tmp_path / "reward.mp4"
    args = ["prompt", ckpt, "--reward", "move-ego-0-0", "--steps", "4"] + (["--video", video] if HAS_RENDERER else [])
    res = run(*args)
    assert res.exit_code == 0, res.output
    assert "return" in res.output and "mean reward" in res.output
    ret = float(res.output.split("return")[1].split()[1])
    assert 0.0 <= ret <= 4.0
    if HAS_RENDERER:
        import imageio.v2 as imageio

        assert len(imageio.mimread(video)) == 5  # the start frame plus one per step
        # rendering and encoding say so, in lines (not a terminal here)
        assert "reward move-ego-0-0, rendering: 100% (4/4)" in res.output and "encoding 5 frames" in res.output


def test_prompt_goal_and_imitate_metrics(ckpt, clip_path):
    res = run("prompt", ckpt, "--goal", "t_pose", "--steps", "3")
    assert res.exit_code == 0, res.output
    assert "final d_smpl" in res.output and "proximity" in res.output and "min d_smpl" in res.output
    # success means the pose was reached at some step, which the final distance alone does not show
    assert "reached (d <= 2 at any step)" in res.output and "success (d <= 2)" not in res.output
    res = run("prompt", ckpt, "--imitate", clip_path, "--steps", "3")
    assert res.exit_code == 0, res.output
    assert "EMD to clip" in res.output


@pytest.mark.parametrize("flag, value", [("--reward", "move-ego-0-0"), ("--goal", "t_pose")])
def test_prompt_refine_searches_and_saves_the_z(ckpt, tmp_path, flag, value):
    out = tmp_path / "z.npy"
    res = run("prompt", ckpt, flag, value, "--steps", "3", "--refine", "2", "--refine-population", "3",
              "--refine-starts", "2", "--save-z", out)
    assert res.exit_code == 0, res.output
    assert "(refined)" in res.output and "episodes, cos(z, z0)" in res.output
    assert "14, " in res.output  # (2 generations x 3 + the final mean) x 2 starts
    before, after = (float(x) for x in re.search(r"(-?[\d.]+) -> (-?[\d.]+)", res.output).groups())
    assert after >= before
    z = np.load(out)
    assert z.shape == (8,) and np.isclose(np.linalg.norm(z), np.sqrt(8), rtol=1e-5)


def test_prompt_goal_method_chooses_the_goal_inference(ckpt, tmp_path):
    zs = {}
    for method in ("backward", "mix"):
        out = tmp_path / f"{method}.npy"
        res = run("prompt", ckpt, "--goal", "t_pose", "--method", method, "--steps", "2", "--save-z", out)
        assert res.exit_code == 0, res.output
        zs[method] = np.load(out)
    bfm = BFM.load(ckpt)
    np.testing.assert_allclose(zs["backward"], bfm.prompt.goal("t_pose"), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(zs["mix"], bfm.prompt.goal("t_pose", method="mix"), rtol=1e-5, atol=1e-6)
    assert np.linalg.norm(zs["mix"] - zs["backward"]) > 1e-3


def test_prompt_refine_needs_a_reward_or_goal(ckpt, clip_path):
    res = run("prompt", ckpt, "--imitate", clip_path, "--refine", "1")
    assert res.exit_code != 0 and "--refine applies to --reward and --goal" in res.output


def test_track_prints_success_and_emd(ckpt, clip_path, tmp_path):
    video = tmp_path / "track.mp4"
    res = run("track", ckpt, clip_path, *(["--video", video] if HAS_RENDERER else []))
    assert res.exit_code == 0, res.output
    assert "tracking success" in res.output and "EMD" in res.output and "8 / 8" in res.output
    if HAS_RENDERER:
        import imageio.v2 as imageio

        frames = imageio.mimread(video)
        assert len(frames) == 8 and frames[0].shape[1] == 2 * frames[0].shape[0] * 320 // 240  # agent | reference


def test_timeline_runs_every_segment(ckpt, clip_path, tmp_path):
    spec = f"move-ego-0-2:0.1,t_pose:0.1,{clip_path}:0.1"
    video = tmp_path / "timeline.mp4"
    res = run("timeline", ckpt, spec, *(["--video", video] if HAS_RENDERER else []))
    assert res.exit_code == 0, res.output
    for text in ("mean reward", "final d_smpl", "EMD to clip", "reward", "goal", "clip"):
        assert text in res.output
    if HAS_RENDERER:
        assert video.stat().st_size > 0


@pytest.mark.parametrize("args, message", [
    (["prompt", "{ckpt}", "--reward", "fly-to-moon"], "unknown reward task 'fly-to-moon'"),
    (["prompt", "{ckpt}", "--goal", "t_pose", "--reward", "jump-2"], "exactly one of"),
    (["prompt", "{ckpt}", "--goal", "t_pose", "--method", "regression"], "unknown goal inference method 'regression'"),
    (["prompt", "{ckpt}", "--imitate", "walk", "--method", "mix"], "does not apply to --imitate"),
    (["prompt", "{missing}", "--goal", "t_pose"], "no such checkpoint directory"),
    (["track", "{ckpt}", "{missing}.npz"], "motion clip not found"),
    (["timeline", "{ckpt}", "jump-2:abc"], "not a number"),
])
def test_bad_input_is_one_clean_line(ckpt, tmp_path, args, message):
    res = run(*[a.format(ckpt=ckpt, missing=tmp_path / "missing") for a in args])
    assert res.exit_code == 1
    assert message in res.output and "Traceback" not in res.output
    assert isinstance(res.exception, SystemExit)


def test_debug_flag_shows_the_exception(ckpt):
    res = run("--debug", "prompt", ckpt, "--reward", "fly-to-moon")
    assert res.exit_code != 0 and "fly-to-moon" in str(res.exception)
    assert not isinstance(res.exception, SystemExit)
    assert run("prompt", ckpt, "--reward", "fly-to-moon").exit_code == 1  # --debug does not stick


def test_cli_loads_from_offline_hub_cache(ckpt, tmp_path):
    """A real process with HF_HUB_OFFLINE=1 and HF_HUB_CACHE: the repo id resolves to the cached snapshot."""
    sha = "89abcdef0123456789abcdef0123456789abcdef"
    repo = tmp_path / "models--org--tiny-bfm"
    shutil.copytree(ckpt, repo / "snapshots" / sha)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(sha)
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "HF_HUB_CACHE": str(tmp_path), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "fbcpr.cli.app"]
    ok = subprocess.run(cmd + ["prompt", "org/tiny-bfm", "--goal", "t_pose", "--steps", "2"],
                        env=env, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert "final d_smpl" in ok.stdout


def test_cli_missing_repo_offline(tmp_path, monkeypatch):
    import huggingface_hub.constants

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path))
    res = run("prompt", "org/not-cached", "--goal", "t_pose")
    assert res.exit_code == 1
    assert "not in the local cache" in res.output and "Traceback" not in res.output


def test_demo_trains_prompts_and_summarizes(tmp_path):
    """`fbcpr demo` end to end with a tiny humanoid config and a step budget (the real demo uses minutes)."""
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text("""
model: {preset: tiny}
agent: {batch_size: 32}
env: {name: humanoid, motions: synthetic, max_episode_steps: 50}
train: {total_env_steps: 100000, num_envs: 4, warmup_steps: 100, rollout_steps: 40, updates_per_rollout: 1,
        buffer_capacity: 2000, priority_every: 0, checkpoint_every: 0, log_every: 100, reward_buffer_size: 300,
        torch_threads: 1}
""")
    out = tmp_path / "demo"
    res = run("demo", "--train", "--config", cfg, "--steps", "160", "--out", out, "--episodes", "1",
              "--eval-steps", "5", "--no-video")
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "demo_summary.json").read_text())
    assert summary["training"]["env_steps"] == 160 and summary["training"]["updates"] > 0
    assert set(summary["scores"]) == {"FB-CPR", "zero action", "random action"}
    assert [s["metric"] for s in summary["scores"]["FB-CPR"]] == ["return", "share held", "EMD"]
    assert 0 <= summary["beats_floors"] <= 3 and "30M env steps" in summary["verdict"]
    assert "zero-shot prompts" in res.output
    again = run("demo", "--train", "--config", cfg, "--steps", "10", "--out", out)  # never overwrites a run
    assert again.exit_code == 1 and "already holds a run" in again.output
    untrained = run("demo", "--steps", "10", "--out", tmp_path / "x")  # training options need --train
    assert untrained.exit_code == 1 and "--steps applies to training" in untrained.output


def test_commands_default_to_the_shipped_model_and_keep_the_positional_forms(ckpt, clip_path):
    """`fbcpr prompt --reward X`, `fbcpr track CLIP`, `fbcpr timeline SPEC` and `fbcpr eval` run the shipped model;
    `--model PATH` or a leading CKPT argument (the older form: `track CKPT CLIP`) names another."""
    shipped = run("prompt", "--reward", "move-ego-0-0", "--steps", "3")
    assert shipped.exit_code == 0, shipped.output
    assert "stored at export" in shipped.output  # the shipped model stores its reward prompts; the tiny one does not
    named = run("prompt", "pretrained", "--reward", "move-ego-0-0", "--steps", "3")
    assert named.exit_code == 0 and "stored at export" in named.output, named.output
    for args in (["prompt", "--model", ckpt], ["prompt", ckpt]):
        res = run(*args, "--reward", "move-ego-0-0", "--steps", "3")
        assert res.exit_code == 0 and "inferred from the checkpoint" in res.output, (args, res.output)
    twice = run("prompt", ckpt, "--model", "pretrained", "--reward", "move-ego-0-0")
    assert twice.exit_code != 0 and "named twice" in twice.output

    for args in (["track", "--model", ckpt, clip_path], ["track", ckpt, clip_path], ["track", "stand"]):
        res = run(*args)
        assert res.exit_code == 0 and "tracking success" in res.output, (args, res.output)
    assert "8 / 8" in run("track", "--model", ckpt, clip_path).output  # one value: the clip
    three = run("track", ckpt, clip_path, clip_path)
    assert three.exit_code != 0 and "[CKPT] CLIP" in three.output

    for args in (["timeline", "move-ego-0-0:0.1"], ["timeline", ckpt, "move-ego-0-0:0.1"]):
        res = run(*args)
        assert res.exit_code == 0 and "mean reward" in res.output, (args, res.output)

    res = run("eval", "--suite", "reward", "--tasks", "move-ego-0-0", "--episodes", "1", "--steps", "3", "--out",
              clip_path.parent / "eval")
    assert res.exit_code == 0, res.output
    assert json.loads((clip_path.parent / "eval" / "results.json").read_text())["agent"] == "pretrained"


def test_a_misspelt_pretrained_gets_a_suggestion():
    res = run("prompt", "pretraind", "--reward", "jump-2")
    assert res.exit_code == 1 and "did you mean 'pretrained'" in res.output


def test_tracking_frames_are_labelled_agent_and_reference():
    from fbcpr.cli.prompt_cmd import side_by_side

    agent, reference = np.full((60, 80, 3), 200, np.uint8), np.full((60, 80, 3), 200, np.uint8)
    frame = side_by_side(agent, reference)
    assert frame.shape == (60, 160, 3)
    left, right = frame[:, :80], frame[:, 80:]
    for half in (left, right):
        label = half[:18, :40]  # the box of the shorter word, "agent"
        assert (label == 0).any() and (label > 100).any()   # light text on a black box
        assert (half[30:] == 200).all()                     # the picture below it untouched
    assert not np.array_equal(left[:18], right[:18])      # two different words
