"""Regression tests from the fault-injection run (issue 16): every bad input ends in the package's own error type,
with a one-line message naming the file, key or argument, and fast (nothing here inflates, trains or imports)."""
from __future__ import annotations

import dataclasses
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from humanoid_env.model import default_qpos
from motions.clip import ClipFormatError, from_qpos, load_clip, save_clip
from motions.importers import UnknownFormatError, detect_format, import_file
from motions.importers.amass import AmassFormatError, read_amass
from motions.importers.bvh import BvhFormatError, parse_bvh
from motions.importers.deepmimic import DeepMimicFormatError, read_frames
from motions.limits import MAX_SECONDS_ENV


# --- motion inputs ------------------------------------------------------------------------------------------------

def _deepmimic(path: Path, durations: list[float]) -> Path:
    rest = [0.0, 0.9, 0.0] + [1.0, 0.0, 0.0, 0.0] * 3 + ([1.0, 0, 0, 0, 0.0] + [1.0, 0, 0, 0]) * 2
    rest += ([1.0, 0, 0, 0, 0.0]) * 2
    rows = [[d] + rest for d in durations]
    assert len(rows[0]) == 44
    path.write_text(json.dumps({"Loop": "none", "Frames": rows}))
    return path


@pytest.mark.parametrize("durations, message", [
    ([3600.0, 0.0], r"frame time 3600 s \(frame 0\) is outside"),
    ([1e-9, 1e-9, 0.0], "frame time 1e-09 s"),
    ([0.0, 0.0], "frame time 0 s"),
    ([-0.03, 0.0], "is outside"),
])
def test_deepmimic_frame_times_are_bounded(tmp_path, durations, message):
    path = _deepmimic(tmp_path / "clip.txt", durations)
    with pytest.raises(DeepMimicFormatError, match=message) as err:
        read_frames(path)
    assert str(path) in str(err.value)


def test_deepmimic_duration_cap_names_the_setting(tmp_path, monkeypatch):
    path = _deepmimic(tmp_path / "clip.txt", [0.5] * 10 + [0.0])
    read_frames(path)
    monkeypatch.setenv(MAX_SECONDS_ENV, "2")
    with pytest.raises(DeepMimicFormatError, match=f"over the 2 s limit.*{MAX_SECONDS_ENV}"):
        read_frames(path)


def test_deeply_nested_json_is_a_format_error(tmp_path):
    path = tmp_path / "deep.txt"
    path.write_text("{\"Frames\": " + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(DeepMimicFormatError, match="nested too deeply"):
        import_file(path, use_cache=False)


def _bvh(frame_time: str, frames: str = "3", depth: int = 1) -> str:
    joints = "".join(f"JOINT J{i} {{ OFFSET 0 1 0 CHANNELS 3 Zrotation Xrotation Yrotation\n" for i in range(depth - 1))
    closing = "}\n" * (depth - 1)
    n_frames = int(float(frames)) if frames.isdigit() else 0
    values = "\n".join(" ".join(["0"] * (6 + 3 * (depth - 1))) for _ in range(n_frames))
    return (f"HIERARCHY\nROOT Hips {{ OFFSET 0 0 0 CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
            f"Yrotation\n{joints}End Site {{ OFFSET 0 1 0 }}\n{closing}}}\nMOTION\nFrames: {frames}\n"
            f"Frame Time: {frame_time}\n{values}\n")


@pytest.mark.parametrize("frame_time, frames, message", [
    ("1e-9", "3", "frame time 1e-09 s"),
    ("inf", "3", "frame time must be finite"),
    ("nan", "3", "frame time must be finite"),
    ("0", "3", "frame time 0 s"),
    ("0.0333", "inf", "expected a count"),
    ("0.0333", "1e12", "over the 600 s limit"),
    ("0.0333", "2.5", "expected a count"),
])
def test_bvh_frame_times_and_counts_are_bounded(frame_time, frames, message):
    with pytest.raises(BvhFormatError, match=message):
        parse_bvh(_bvh(frame_time, frames), "walk.bvh")


def test_bvh_deep_nesting_is_a_format_error():
    with pytest.raises(BvhFormatError, match="walk.bvh: joints nested more than"):
        parse_bvh(_bvh("0.0333", "3", depth=5000), "walk.bvh")


def _npz_with_header(path: Path, members: dict[str, tuple[tuple[int, ...], str]]) -> Path:
    """An .npz whose members declare `shape`/`dtype` in their headers but hold almost no data."""
    with zipfile.ZipFile(path, "w") as zf:
        for key, (shape, descr) in members.items():
            buf = io.BytesIO()
            np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
            zf.writestr(f"{key}.npy", buf.getvalue() + b"\0" * 64)
    return path


def _amass(path: Path, fps: float, n: int = 40) -> Path:
    np.savez(path, poses=np.zeros((n, 72)), trans=np.zeros((n, 3)), mocap_framerate=np.float64(fps))
    return path


@pytest.mark.parametrize("fps, message", [
    (1e-6, "outside"), (1e9, "outside"), (0.0, "must be a positive, finite number"), (-30.0, "outside"),
    (np.nan, "must be a positive, finite number"), (np.inf, "outside"),
])
def test_amass_frame_rates_are_bounded(tmp_path, fps, message):
    path = _amass(tmp_path / "a.npz", fps)
    with pytest.raises(AmassFormatError, match=message) as err:
        read_amass(path)
    assert str(path) in str(err.value)


def test_amass_headers_are_checked_before_reading(tmp_path):
    path = _npz_with_header(tmp_path / "huge.npz", {"poses": ((10**12, 76), "<f8"), "trans": ((10**12, 3), "<f8"),
                                                       "mocap_framerate": ((), "<f8")})
    with pytest.raises(AmassFormatError, match="'poses' declares"):
        read_amass(path)


@pytest.mark.parametrize("content, message", [
    (b"\x93NUMPY plain npy", "not a valid clip archive"),
    (b"{\"Frames\": []}", "not a valid clip archive"),
    (os.urandom(256), "not a valid clip archive"),
])
def test_non_archives_are_not_valid_clips_and_never_suggest_unpickling(tmp_path, content, message):
    path = tmp_path / "clip.npz"
    path.write_bytes(content)
    with pytest.raises(ClipFormatError, match=message) as err:
        load_clip(path)
    assert "pickle" not in str(err.value) and str(path) in str(err.value)


def test_a_real_npy_renamed_npz_is_not_a_clip(tmp_path):
    np.save(tmp_path / "x.npy", np.zeros((3, 76)))
    path = tmp_path / "x.npz"
    (tmp_path / "x.npy").rename(path)
    with pytest.raises(ClipFormatError, match="not a valid clip archive"):
        load_clip(path)


def test_a_motion_file_given_as_a_clip_says_import_it_first(tmp_path):
    path = _deepmimic(tmp_path / "walk.txt", [0.03] * 5)
    with pytest.raises(ClipFormatError, match="import it first with `fbcpr motions import`"):
        load_clip(path)


@pytest.mark.parametrize("members, message", [
    ({"qpos": ((10**12, 76), "<f8")}, "declares 1000000000000 frames"),
    ({"qpos": ((3, 76), "|O")}, "never unpickled"),
])
def test_clip_headers_are_checked_before_reading(tmp_path, members, message):
    path = _npz_with_header(tmp_path / "c.npz", members)
    with pytest.raises(ClipFormatError, match=message):
        load_clip(path)


def _clip(n: int = 12):
    q = np.repeat(default_qpos()[None], n, axis=0)
    q[:, 0] = 0.5 * np.arange(n) / 30.0
    return from_qpos(q, name="probe", source="test", license="MIT")


def _rewrite(path: Path, **changes: np.ndarray) -> None:
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(path, **arrays)


def test_every_frame_is_checked(tmp_path):
    clip = _clip()
    path = save_clip(clip, tmp_path / "c.npz")
    obs = clip.obs.copy()
    obs[5] += 0.5
    _rewrite(path, obs=obs)
    with pytest.raises(ClipFormatError, match="first at frame 5"):
        load_clip(path)


def test_root_teleport_is_rejected(tmp_path):
    q = np.repeat(default_qpos()[None], 12, axis=0)
    q[6:, 0] += 50.0
    with pytest.raises(ClipFormatError, match="root moves .* between frames 5 and 6"):
        from_qpos(q, name="teleport")


def test_named_pipe_is_refused_not_read(tmp_path):
    fifo = tmp_path / "pipe.bvh"
    os.mkfifo(fifo)
    with pytest.raises(UnknownFormatError, match="not a regular file"):
        detect_format(fifo)


def test_motions_info_lists_good_clips_beside_bad_ones(tmp_path):
    from fbcpr.cli.app import app

    save_clip(_clip(), tmp_path / "good.npz")
    np.save(tmp_path / "bad.npy", np.zeros(3))
    (tmp_path / "bad.npy").rename(tmp_path / "bad.npz")
    res = CliRunner().invoke(app, ["motions", "info", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "probe" in res.output and "invalid" in res.output


# --- configs --------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("section, key, value", [
    ("train", "num_envs", 10**30), ("train", "buffer_capacity", 10**12), ("model", "hidden_dim", 10**9),
    ("model", "z_dim", 10**6), ("agent", "batch_size", 10**9), ("model", "hidden_layers", 10**4),
])
def test_config_ranges_name_the_key(section, key, value):
    from fbcpr.core.config import config_from_dict
    from fbcpr.core.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"^{section}\.{key}: must be"):
        config_from_dict({section: {key: value}})


@pytest.mark.parametrize("content, message", [
    (b"train:\n  num_envs: 4\n  num_envs: 8\n", r"c\.yaml:3:3: invalid YAML: duplicate key 'num_envs'"),
    (b"train: {seed: 1, seed: 2}\n", "duplicate key 'seed'"),
    (b"train:\n  seed: \xff\xfe\n", "not UTF-8 text"),
])
def test_bad_config_files_are_config_errors(tmp_path, content, message):
    from fbcpr.core.config import load_config
    from fbcpr.core.errors import ConfigError

    path = tmp_path / "c.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_a_directory_as_config_is_a_config_error(tmp_path):
    from fbcpr.core.config import load_config
    from fbcpr.core.errors import ConfigError

    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)


# --- timelines ------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, message", [
    ("jump-2:1e9", "'jump-2:1e9': duration must be a positive number of seconds, at most 3600"),
    ("jump-2:inf", "at most 3600"), ("jump-2:nan", "positive number"), ("jump-2:0", "positive number"),
])
def test_timeline_durations_are_bounded(text, message):
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.timeline import parse_timeline

    with pytest.raises(PromptError, match=message):
        parse_timeline(text)


def test_timeline_total_is_bounded_before_any_prompt_runs():
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.timeline import Timeline

    with pytest.raises(PromptError, match=r"segment 2 \(walk\): the timeline would last 4000 s"):
        Timeline.build(prompt=None, items=[("walk", 2000.0), ("walk", 2000.0)])


# --- checkpoints ----------------------------------------------------------------------------------------------------

def _checkpoint(tmp_path: Path) -> Path:
    import torch

    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}})
    torch.manual_seed(0)
    return save_checkpoint(tmp_path / "run" / "checkpoints" / "step_0000000010", FBCPRModel(cfg.model), cfg)


@pytest.mark.parametrize("edit, message", [
    (lambda m: m.update(files=list(m["files"])), "'files' must map file names"),
    (lambda m: m["files"]["model.safetensors"].pop("bytes"), "files.model.safetensors: must be"),
    (lambda m: m["files"]["config.yaml"].update(sha256=5), "files.config.yaml: must be"),
    (lambda m: m.update(algorithm=["fb_cpr"]), "'algorithm' must be a string"),
    (lambda m: m.update(format_version="1"), "format_version '1' is not supported"),
])
def test_malformed_manifest_is_a_checkpoint_error(tmp_path, edit, message):
    from fbcpr.core.checkpoint import CheckpointError, load_checkpoint

    path = _checkpoint(tmp_path)
    manifest = json.loads((path / "manifest.json").read_text())
    edit(manifest)
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(path)


def test_binary_manifest_is_a_checkpoint_error(tmp_path):
    from fbcpr.core.checkpoint import CheckpointError, load_checkpoint

    path = _checkpoint(tmp_path)
    (path / "manifest.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(CheckpointError, match="manifest.json: invalid JSON"):
        load_checkpoint(path)


@pytest.mark.parametrize("pointer", ["", ".", "latest", "../elsewhere"])
def test_bad_latest_pointer_is_named(tmp_path, pointer):
    from fbcpr.inference.bfm import BFM
    from fbcpr.core.checkpoint import CheckpointError
    from fbcpr.train.trainer import checkpoint_env_steps

    path = _checkpoint(tmp_path)
    (path.parent / "latest").write_text(pointer)
    with pytest.raises(CheckpointError, match=r"checkpoints/latest: must name a checkpoint folder"):
        BFM.load(tmp_path / "run")
    with pytest.raises(CheckpointError, match=r"checkpoints/latest: must name"):
        checkpoint_env_steps(tmp_path / "run")


def test_overlong_checkpoint_path_is_a_checkpoint_error():
    from fbcpr.inference.bfm import BFM
    from fbcpr.core.checkpoint import CheckpointError

    with pytest.raises(CheckpointError, match="not a usable checkpoint path"):
        BFM.load("a" * 300 + "/b")


# --- non-finite values ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad, message", [
    (np.inf, "contains NaN or inf"), (np.nan, "contains NaN or inf"), ("x", "must be numbers"),
])
def test_env_checks_actions_before_clipping(bad, message):
    from humanoid_env.actions import InvalidActionError
    from humanoid_env.env import HumanoidEnv
    from humanoid_env.model import NU

    env = HumanoidEnv()
    env.reset(seed=0)
    action = np.zeros(NU, dtype=object if isinstance(bad, str) else np.float64)
    action[3] = bad
    with pytest.raises(InvalidActionError, match=rf"^action {message}"):
        env.step(action)


def test_vector_env_checks_actions_before_clipping():
    from humanoid_env.actions import InvalidActionError
    from humanoid_env.model import NU
    from humanoid_env.vector import VectorHumanoidEnv

    env = VectorHumanoidEnv(2, num_threads=1)
    env.reset(seed=0)
    actions = np.zeros((2, NU))
    actions[1, 0] = np.inf
    with pytest.raises(InvalidActionError, match=r"actions contain NaN or inf \(envs \[1\]\)"):
        env.step(actions)


@pytest.mark.parametrize("index, value", [(2, 1e39), (7 + 76, 1e300)])
def test_env_never_emits_non_finite_observations(index, value):
    from humanoid_env.env import HumanoidEnv
    from humanoid_env.model import NQ, default_qpos

    qpos, qvel = default_qpos().copy(), np.zeros(75)
    if index < NQ:
        qpos[index] = value
    else:
        qvel[index - NQ] = value
    env = HumanoidEnv()
    with pytest.raises(ValueError, match="reset: the state's observation is not finite"):
        env.reset(seed=0, options={"qpos": qpos, "qvel": qvel})


def test_buffer_drops_and_counts_non_finite_rows():
    from fbcpr.train.buffer import ReplayBuffer, transition_specs

    buf = ReplayBuffer(10, transition_specs(4, 2, 3, 5, 5))
    batch = {k: np.zeros((3, *s), dtype=np.float64) for k, s in buf.specs.items()}
    batch["qpos"][1, 0] = 1e39  # finite float64, inf as float32
    batch["obs"][2, 0] = np.nan
    buf.add(batch)
    assert (len(buf), buf.dropped) == (1, 2)
    assert all(np.isfinite(v[: len(buf)]).all() for v in buf.data.values())


def test_states_only_reward_samples_that_cannot_be_rebuilt_are_named(tmp_path, monkeypatch):
    from conftest import humanoid_states
    from fbcpr import BFM
    from fbcpr.core import checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69}})
    model, states = FBCPRModel(cfg.model), humanoid_states(8, seed=0)

    def saved(name: str, **change: np.ndarray):
        buf = {**states, **change}
        path = checkpoint.save_checkpoint(tmp_path / name, model, cfg, reward_buffer=buf, reward_obs=False)
        return BFM.load(path)

    assert saved("ok").reward_buffer["next_obs"].shape == (8, 358)  # rebuilt on load
    monkeypatch.setattr(checkpoint, "MAX_REBUILT_STATES", 7)
    with pytest.raises(checkpoint.CheckpointError, match="8 states without observations; loading rebuilds at most 7"):
        saved("ok").reward_buffer
    monkeypatch.undo()
    with pytest.raises(checkpoint.CheckpointError, match="reward_buffer.safetensors: .*qpos"):
        saved("narrow", qpos=states["qpos"][:, :70]).reward_buffer
    zero_quat = states["qpos"].copy()
    zero_quat[2, 3:7] = 0.0  # no orientation: its observation cannot be rebuilt
    with np.errstate(invalid="ignore", divide="ignore"), pytest.raises(checkpoint.CheckpointError, match="NaN"):
        saved("zero-quaternion", qpos=zero_quat).prompt.reward("move-ego-0-0")


def test_checkpoint_reward_buffer_is_filtered_on_save(tmp_path):
    import torch

    from fbcpr.core.checkpoint import load_checkpoint, save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}})
    reward = {"next_obs": np.zeros((4, 6)), "qpos": np.zeros((4, 4)), "qvel": np.zeros((4, 3))}
    reward["qpos"][0, 0] = np.inf
    reward["qvel"][3, 0] = 1e6  # finite in float32, inf in float16
    save_checkpoint(tmp_path / "c", FBCPRModel(cfg.model), cfg, reward_buffer=reward, reward_dtype=torch.float16)
    assert load_checkpoint(tmp_path / "c").reward_buffer()["qpos"].shape == (2, 4)


def _bfm():
    import torch

    from fbcpr.inference.bfm import BFM
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}})
    torch.manual_seed(0)
    return BFM(FBCPRModel(cfg.model), cfg)


def test_act_projects_z_onto_the_sphere():
    bfm = _bfm()
    obs = np.ones(6, dtype=np.float32)
    z = np.full(bfm.z_dim, 1.0, dtype=np.float32)
    a = bfm.act(obs, z * 1e30)
    assert np.isfinite(a).all()
    np.testing.assert_allclose(a, bfm.act(obs, z), atol=1e-6)


@pytest.mark.parametrize("obs_value, z_value, message", [
    (3e38, 1.0, "obs: gives non-finite actions"), (1.0, 0.0, "z: must be nonzero"),
])
def test_act_never_returns_non_finite_actions(obs_value, z_value, message):
    from fbcpr.core.errors import InputError

    bfm = _bfm()
    with pytest.raises(InputError, match=message):
        bfm.act(np.full(6, obs_value, dtype=np.float32), np.full(bfm.z_dim, z_value, dtype=np.float32))


@pytest.mark.parametrize("temperature", [-1.0, np.nan, np.inf])
def test_reward_temperature_is_validated_and_named(temperature):
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.prompt import Prompt

    with pytest.raises(PromptError, match="temperature: must be a finite number >= 0"):
        Prompt(_bfm()).reward(lambda *a: np.zeros(1), temperature=temperature)


# --- crash leftovers and resume ------------------------------------------------------------------------------------

def test_pruning_never_leaves_a_half_deleted_checkpoint_under_its_name(tmp_path, monkeypatch):
    import fbcpr.core.checkpoint as ckpt_mod

    path = _checkpoint(tmp_path)

    def killed(p, ignore_errors=False):
        (Path(p) / "model.safetensors").unlink()  # part of the folder is gone, then the process dies
        raise KeyboardInterrupt

    monkeypatch.setattr(ckpt_mod.shutil, "rmtree", killed)
    with pytest.raises(KeyboardInterrupt):
        ckpt_mod.discard_checkpoint(path)
    assert not path.exists()
    monkeypatch.undo()
    assert [p.name.split(".deleting-")[0] for p in ckpt_mod.remove_stale_temporaries(path.parent)] == [f".{path.name}"]
    assert sorted(p.name for p in path.parent.iterdir()) == []


def _toy_trainer(out: Path, **train):
    from fbcpr.core.config import config_from_dict
    from fbcpr.train.trainer import Trainer

    cfg = config_from_dict({"model": {"preset": "tiny"}, "agent": {"batch_size": 32},
                            "env": {"name": "toy", "max_episode_steps": 30},
                            "train": {"num_envs": 4, "buffer_capacity": 1000, "reward_buffer_size": 50,
                                      "torch_threads": 1, "eval_every": 0, "priority_every": 0, **train}})
    return Trainer(cfg, out, progress=False)


def test_stale_save_temporaries_are_removed_at_start_and_backups_kept(tmp_path):
    root = tmp_path / "run" / "checkpoints"
    for name in (".step_0000000010.tmp-1a2b3c4d", ".step_0000000020.deleting-00ff00ff", ".step_0000000030.previous"):
        (root / name).mkdir(parents=True)
        (root / name / "model.safetensors").write_bytes(b"x" * 100)
    (root / ".latest.tmp").write_text("step_0000000010")
    _toy_trainer(tmp_path / "run")
    assert sorted(p.name for p in root.iterdir()) == [".step_0000000030.previous"]


def test_checkpoint_records_the_next_checkpoint_not_the_current_one(tmp_path):
    import time

    from fbcpr.train.trainer import checkpoint_env_steps
    from fbcpr.core.checkpoint import read_trainer_meta

    tr = _toy_trainer(tmp_path / "run", checkpoint_every=40, log_every=10**6)
    tr.env_steps = 40
    tr._periodic(time.perf_counter(), 0, 1000)
    meta = read_trainer_meta(tmp_path / "run" / "checkpoints" / "step_0000000040")
    assert checkpoint_env_steps(tmp_path / "run") == 40 and meta["next_ckpt"] == 80


@pytest.mark.parametrize("train, model, message", [
    ({}, {"hidden_dim": 16384, "hidden_layers": 8}, r"^model: .* parameters need about .* lower model.hidden_dim"),
    ({"buffer_capacity": 10**9, "buffer_memmap_mb": 10**9}, {}, r"^train.buffer_capacity: the replay buffer needs"),
    ({"buffer_capacity": 10**9, "buffer_memmap_mb": 0}, {}, r"^train.buffer_capacity: the memory-mapped replay buffer"),
])
def test_memory_is_estimated_up_front_naming_the_key(tmp_path, monkeypatch, train, model, message):
    import shutil

    import fbcpr.train.resources as resources
    import fbcpr.train.trainer as trainer_mod
    from fbcpr.core.config import config_from_dict
    from fbcpr.core.errors import ConfigError

    monkeypatch.setattr(resources, "memory_bytes", lambda device: 8 * 2**30)
    monkeypatch.setattr(resources.shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(2**40, 2**40 - 2**30, 2**30))
    cfg = config_from_dict({"model": {"preset": "tiny", **model}, "env": {"name": "toy"},
                            "train": {"num_envs": 2, **train}})
    with pytest.raises(ConfigError, match=message):
        trainer_mod.Trainer(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_a_full_disk_fails_in_one_line_before_anything_is_written(tmp_path, monkeypatch):
    import shutil

    import fbcpr.train.resources as resources
    import fbcpr.train.trainer as trainer_mod
    from fbcpr.core.checkpoint import CheckpointError
    from fbcpr.core.config import config_from_dict

    monkeypatch.setattr(resources.shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(2**40, 2**40, 2**16))
    cfg = config_from_dict({"model": {"preset": "tiny"}, "env": {"name": "toy"}, "train": {"num_envs": 2}})
    with pytest.raises(CheckpointError, match=r"MiB free on disk, but one checkpoint of this run needs about"):
        trainer_mod.Trainer(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("call, error", [
    (lambda: __import__("fbcpr.metrics", fromlist=["x"]).emd(np.zeros((0, 3)), np.zeros((2, 3))),
     "fbcpr.core.errors:InputError"),
    (lambda: __import__("humanoid_env.vector", fromlist=["x"]).VectorHumanoidEnv(0), "humanoid_env.errors:EnvError"),
    (lambda: __import__("humanoid_env.vector", fromlist=["x"]).VectorHumanoidEnv(2).reset(
        options={"qpos": np.zeros((3, 76)), "qvel": np.zeros((3, 75))}), "humanoid_env.errors:InvalidStateError"),
    (lambda: __import__("fbcpr.core.config", fromlist=["x"]).config_from_dict({"nope": 1}), "fbcpr.core.errors:FBCPRError"),
])
def test_bad_input_ends_in_the_packages_own_error_types(call, error):
    import importlib

    module, name = error.split(":")
    with pytest.raises(getattr(importlib.import_module(module), name)):
        call()


def test_resume_with_other_num_envs_names_the_key(tmp_path):
    from fbcpr.core.errors import ConfigError
    from fbcpr.train.trainer import Trainer

    tr = _toy_trainer(tmp_path / "run")
    tr.save()
    cfg = dataclasses.replace(tr.cfg, train=dataclasses.replace(tr.cfg.train, num_envs=8))
    with pytest.raises(ConfigError, match=r"^train.num_envs: 8, but .* was saved with 4 envs"):
        Trainer(cfg, tmp_path / "run", resume=True, progress=False)


# --- issue 58: outputs apart from their sources, real inputs, exact resume, named fields ----------------------------

def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _trained_checkpoint(tmp_path: Path) -> Path:
    """A checkpoint with a trainer state, as a run writes it: what an export over it would destroy."""
    import torch

    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}})
    path = save_checkpoint(tmp_path / "run" / "checkpoints" / "step_0000000010", FBCPRModel(cfg.model), cfg,
                           trainer_state=({"x": torch.zeros(3)}, {"env_steps": 10}))
    (path.parent / "latest").write_text(path.name)
    return path


@pytest.mark.parametrize("out", ["same", "inside", "containing", "run", "link"])
def test_export_refuses_an_output_that_is_inside_or_contains_its_source(tmp_path, out):
    from fbcpr.cli.app import app

    ckpt = _trained_checkpoint(tmp_path)
    run = tmp_path / "run"
    (tmp_path / "link").symlink_to(ckpt)
    target = {"same": ckpt, "inside": ckpt / "export", "containing": ckpt.parent, "run": run,
              "link": tmp_path / "link"}[out]
    before = _files(run)
    res = CliRunner().invoke(app, ["export", str(run if out == "run" else ckpt), str(target)])
    assert res.exit_code == 1, res.output
    assert "OUT: " in res.output and "the checkpoint to export" in res.output
    assert _files(run) == before  # nothing written, nothing replaced: trainer_state.safetensors is still there


def test_export_refuses_to_replace_a_file_or_a_folder_that_is_no_checkpoint(tmp_path):
    from fbcpr.cli.app import app
    from fbcpr.core.checkpoint import CheckpointError

    ckpt = _trained_checkpoint(tmp_path)
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me")
    res = CliRunner().invoke(app, ["export", str(ckpt), str(notes)])
    assert res.exit_code == 1 and "is an existing file, not a folder" in res.output
    assert notes.read_text() == "keep me"
    folder = tmp_path / "documents"
    folder.mkdir()
    (folder / "thesis.tex").write_text("years of work")
    bfm = _bfm()
    with pytest.raises(CheckpointError, match="documents: a folder that holds files but no checkpoint"):
        bfm.save(folder)
    with pytest.raises(CheckpointError, match="notes.txt: an existing file, not a checkpoint folder"):
        bfm.save(notes)
    assert (folder / "thesis.tex").read_text() == "years of work" and notes.read_text() == "keep me"
    assert (bfm.save(tmp_path / "empty") / "manifest.json").is_file()  # a new or empty folder, or a checkpoint:
    assert (bfm.save(tmp_path / "empty") / "manifest.json").is_file()  # written (again) as before


def test_every_command_that_writes_a_folder_keeps_it_apart_from_its_inputs(tmp_path):
    from fbcpr.cli.app import app

    ckpt = _trained_checkpoint(tmp_path)
    before = _files(tmp_path / "run")
    runner = CliRunner()
    res = runner.invoke(app, ["train", "toy", "--out", str(ckpt / "run"), "--init-from", str(ckpt)])
    assert res.exit_code == 1 and "--out: " in res.output and "lies inside --init-from" in res.output, res.output
    res = runner.invoke(app, ["npmp", "distill", str(ckpt), "--motions", str(tmp_path), "--out", str(tmp_path / "n")])
    assert res.exit_code == 1 and "--out: " in res.output and "lies inside --motions" in res.output, res.output
    assert _files(tmp_path / "run") == before and not (tmp_path / "n").exists()
    source = _amass(tmp_path / "walk.npz", 30.0)
    raw = source.read_bytes()
    res = runner.invoke(app, ["motions", "import", str(source), "--out", str(tmp_path)])
    assert res.exit_code == 1 and "--out: " in res.output and "contains the source" in res.output, res.output
    assert source.read_bytes() == raw  # the clip walk.npz would have replaced the AMASS file walk.npz


@pytest.mark.parametrize("make", [
    lambda: np.ones(6, dtype=np.complex64) * 1j,
    lambda: __import__("torch").ones(6, dtype=__import__("torch").complex64),
    lambda: np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0 + 2j]),
])
def test_act_refuses_complex_observations(make):
    from fbcpr.core.errors import InputError

    bfm = _bfm()
    with pytest.raises(InputError, match=r"^obs: must be real numbers, got complex"):
        bfm.act(make(), np.ones(bfm.z_dim, dtype=np.float32))
    with pytest.raises(InputError, match=r"^z: must be real numbers"):
        bfm.act(np.ones(6, dtype=np.float32), np.ones(bfm.z_dim, dtype=np.complex128))


def test_act_says_a_z_of_none_is_not_numbers():
    from fbcpr.core.errors import InputError

    bfm = _bfm()
    with pytest.raises(InputError, match=r"^z: must be numbers, found NoneType values \(None\)"):
        bfm.act(np.ones(6, dtype=np.float32), [None] * bfm.z_dim)
    with pytest.raises(InputError, match=r"^obs: must be numbers, got an array of <U1"):
        bfm.act(np.array(list("123456")), np.ones(bfm.z_dim))
    mixed = np.array([1, 2.5, True, np.float32(3), 4, 5], dtype=object)  # numbers in an object array still work
    assert bfm.act(mixed, np.ones(bfm.z_dim)).shape == (3,)


@pytest.mark.parametrize("edit, message", [
    (lambda m: m["model"].update(z_dim=m["model"]["z_dim"] + 1), r"manifest.json: model.z_dim: \d+ disagrees"),
    (lambda m: m["model"].update(obs_dim=True), "manifest.json: model.obs_dim: True disagrees"),
    (lambda m: m.update(model=[1]), "manifest.json: model: must map"),
    (lambda m: m["tensors"]["model.safetensors"].update({"obs_normalizer.mean": [7]}),
     r"manifest.json: tensors.model.safetensors: disagrees with model.safetensors \(at 'obs_normalizer.mean'"),
    (lambda m: m["tensors"].pop("model.safetensors"), "manifest.json: tensors.model.safetensors: missing"),
    (lambda m: m.update(tensors="x"), "manifest.json: tensors: must map"),
])
def test_manifest_sizes_and_shapes_are_checked(tmp_path, edit, message):
    from fbcpr.core.checkpoint import CheckpointError, load_checkpoint

    path = _checkpoint(tmp_path)
    manifest = json.loads((path / "manifest.json").read_text())
    assert "obs_normalizer.mean" in manifest["tensors"]["model.safetensors"]
    edit(manifest)
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(path)


@pytest.mark.parametrize("edit, message", [
    (("CHANNELS 6", "CHANNELS 2.7"), r"walk.bvh:2: CHANNELS of joint Hips: expected a count .*, got 2.7$"),
    (("CHANNELS 6", "CHANNELS -1"), r"walk.bvh:2: CHANNELS of joint Hips: expected a count .*, got -1$"),
    (("Frames: 3", "Frames: -5"), r"walk.bvh:6: Frames: expected a count .*, got -5$"),
    (("Frames: 3", "Frames: 2.5"), r"walk.bvh:6: Frames: expected a count .*, got 2.5$"),
])
def test_bvh_counts_name_the_field_and_line(edit, message):
    text = _bvh("0.0333", "3")
    assert edit[0] in text
    with pytest.raises(BvhFormatError, match=message):
        parse_bvh(text.replace(edit[0], edit[1]), "walk.bvh")


@pytest.mark.parametrize("fps", [0.0, np.nan, -30.0, np.inf, 1e-6])
def test_amass_frame_rate_errors_name_mocap_framerate(tmp_path, fps):
    path = _amass(tmp_path / "a.npz", fps)
    with pytest.raises(AmassFormatError, match=f"a.npz: mocap_framerate {fps:g}|a.npz: mocap_framerate must be"):
        read_amass(path)


def test_a_latest_symlink_loop_is_named(tmp_path):
    from fbcpr.core.checkpoint import CheckpointError
    from fbcpr.inference.bfm import BFM
    from fbcpr.train.trainer import checkpoint_env_steps

    path = _checkpoint(tmp_path)
    (path.parent / "latest").symlink_to("latest")
    for load in (lambda: BFM.load(tmp_path / "run"), lambda: BFM.load(path.parent / "latest"),
                 lambda: checkpoint_env_steps(tmp_path / "run")):
        with pytest.raises(CheckpointError, match=r"checkpoints/latest: a symbolic link loop"):
            load()


@pytest.mark.parametrize("typed, message", [
    ("jump-2*", r"malformed reward expression .*: 'jump-2\*'"),
    ("+jump-2", r"malformed reward expression .*: '\+jump-2'"),
    ("jump-2*jumpp-2", r"^in 'jump-2\*jumpp-2': unknown reward task 'jumpp-2'"),
])
def test_reward_expressions_echo_what_was_typed(typed, message):
    from fbcpr.core.errors import PromptError
    from fbcpr.inference.prompt import reward_fn

    with pytest.raises(PromptError, match=message):
        reward_fn(typed)


def test_stored_reward_prompts_without_metadata_say_so(tmp_path):
    import torch

    from fbcpr.core.checkpoint import CheckpointError, save_checkpoint
    from fbcpr.inference.bfm import BFM

    bfm = _bfm()
    path = save_checkpoint(tmp_path / "c", bfm.model, bfm.config,
                           reward_prompts=({"jump-2": torch.ones(bfm.z_dim)}, {}))
    with pytest.raises(CheckpointError, match=r"reward_prompts.safetensors: its metadata is missing \(method, "
                                              r"temperature, digest, states\)"):
        BFM.load(path)


def test_a_world_size_that_does_not_fit_fails_before_the_process_group_starts(tmp_path, monkeypatch):
    import fbcpr.train.trainer as trainer_mod
    from fbcpr.core.config import config_from_dict
    from fbcpr.core.errors import ConfigError

    def started(*args, **kwargs):
        raise AssertionError("the process group was started")

    monkeypatch.setattr(trainer_mod.distributed, "setup", started)
    monkeypatch.setenv("WORLD_SIZE", "3")
    monkeypatch.setenv("RANK", "1")
    cfg = config_from_dict({"model": {"preset": "tiny"}, "env": {"name": "toy"},
                            "train": {"num_envs": 4, "rollout_steps": 40}})
    with pytest.raises(ConfigError, match=r"^train.rollout_steps: .* do not split over 3 ranks"):
        trainer_mod.Trainer(cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_env_state_restores_every_bit_of_the_simulation():
    from humanoid_env.vector import VectorHumanoidEnv

    env = VectorHumanoidEnv(2, num_threads=1)
    env.reset(seed=0)
    for _ in range(20):  # standing still on its feet: contacts, so the solver's warm start counts
        env.step(np.zeros((2, 69)))
    qpos, qvel, steps = env.get_state()
    state = env.save_state()
    ahead = [env.step(np.zeros((2, 69)))[4]["qpos"] for _ in range(3)]
    from_qpos = VectorHumanoidEnv(2, num_threads=1)
    from_qpos.reset(options={"qpos": qpos, "qvel": qvel})
    assert any((from_qpos.step(np.zeros((2, 69)))[4]["qpos"] != q).any() for q in ahead)  # what qpos/qvel lose
    restored = VectorHumanoidEnv(2, num_threads=1)
    restored.reset(seed=5)
    np.testing.assert_array_equal(restored.load_state(state), state["obs"])
    for q in ahead:
        np.testing.assert_array_equal(restored.step(np.zeros((2, 69)))[4]["qpos"], q)
    assert restored.get_state()[2].tolist() == (steps + 3).tolist()


def test_resume_restores_the_envs_whole_physics_state(tmp_path):
    from fbcpr.core.config import config_from_dict
    from fbcpr.train.trainer import Trainer

    cfg = config_from_dict({"model": {"preset": "tiny"}, "agent": {"batch_size": 32},
                            "train": {"num_envs": 2, "buffer_capacity": 1000, "reward_buffer_size": 50,
                                      "torch_threads": 1, "env_threads": 1, "eval_every": 0, "priority_every": 0,
                                      "warmup_steps": 10**6, "rollout_steps": 2}})
    a = Trainer(cfg, tmp_path / "run", progress=False)
    for _ in range(10):
        a.collector.step()
    a.save()
    b = Trainer(cfg, tmp_path / "run", resume=True, progress=False)
    np.testing.assert_array_equal(b.bundle.env.batch.state, a.bundle.env.batch.state)  # warm start and clock too
    np.testing.assert_array_equal(b.collector.obs, a.collector.obs)
    for _ in range(3):
        a.collector.step()
        b.collector.step()
    np.testing.assert_array_equal(b.bundle.env.batch.state, a.bundle.env.batch.state)
    a.close()
    b.close()
