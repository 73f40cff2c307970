"""BFM: act() conventions, save/load, the Hugging Face cache layout offline, the hub folder and push."""
from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import huggingface_hub
import huggingface_hub.constants
import numpy as np
import pytest
import torch
import yaml

from conftest import humanoid_states
from fbcpr import BFM
from fbcpr.core.checkpoint import CheckpointError, save_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel

torch.set_num_threads(1)
SHA = "0123456789abcdef0123456789abcdef01234567"


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    model = FBCPRModel(cfg.model)
    rng = np.random.default_rng(0)
    model.obs_normalizer.update(torch.as_tensor(rng.normal(size=(64, 358))))
    buf = humanoid_states(32, seed=0)
    return save_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny", model, cfg, reward_buffer=buf)


@pytest.fixture(scope="module")
def bfm(ckpt) -> BFM:
    return BFM.load(ckpt)


def test_act_numpy_and_torch_single_and_batched(bfm):
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(5, 358)).astype(np.float32)
    z = bfm.project_z(rng.normal(size=bfm.z_dim))
    batched = bfm.act(obs, z)
    assert isinstance(batched, np.ndarray) and batched.shape == (5, 69) and np.all(np.abs(batched) <= 1)
    single = bfm.act(obs[2], z)
    assert isinstance(single, np.ndarray) and single.shape == (69,)
    np.testing.assert_allclose(single, batched[2], atol=1e-6)
    t_batched = bfm.act(torch.as_tensor(obs), torch.as_tensor(z))
    assert isinstance(t_batched, torch.Tensor) and t_batched.shape == (5, 69) and not t_batched.requires_grad
    np.testing.assert_allclose(t_batched.numpy(), batched, atol=1e-6)
    t_single = bfm.act(torch.as_tensor(obs[0]), z)
    assert isinstance(t_single, torch.Tensor) and t_single.shape == (69,)
    # per-row zs, float64 input, and the model's own act agree
    zs = bfm.project_z(rng.normal(size=(5, bfm.z_dim)))
    np.testing.assert_allclose(bfm.act(obs.astype(np.float64), zs), bfm.model.act(obs, zs), atol=1e-6)
    # different zs give different actions; sampling adds noise around the mean
    assert np.abs(bfm.act(obs, zs) - batched).max() > 1e-4
    g = torch.Generator().manual_seed(0)
    sampled = bfm.act(obs, z, mean=False, generator=g)
    assert np.abs(sampled - batched).max() > 1e-3 and np.all(np.abs(sampled) <= 1)


@pytest.mark.parametrize("obs_shape, z_shape, match", [
    ((357,), (8,), r"obs: expected shape \(358,\)"),
    ((2, 3, 358), (8,), "obs: expected"),
    ((4, 358), (7,), r"z: expected shape \(8,\)"),
    ((4, 358), (3, 8), r"z: expected shape \(8,\) or \(4, 8\)"),
])
def test_act_rejects_wrong_shapes(bfm, obs_shape, z_shape, match):
    with pytest.raises(ValueError, match=match):
        bfm.act(np.zeros(obs_shape, np.float32), np.ones(z_shape, np.float32))


def test_act_accepts_read_only_arrays_quietly(bfm):
    """A z broadcast over a batch is a read-only view; act must take it without torch's non-writable warning."""
    import warnings

    rng = np.random.default_rng(2)
    obs = rng.normal(size=(4, 358)).astype(np.float32)
    z = bfm.project_z(rng.normal(size=bfm.z_dim))
    view = np.broadcast_to(z, (4, bfm.z_dim))
    assert not view.flags.writeable
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = bfm.act(obs, view)
    np.testing.assert_allclose(out, bfm.act(obs, np.tile(z, (4, 1))), atol=1e-6)


def test_act_rejects_nan(bfm):
    obs = np.zeros(358, np.float32)
    obs[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        bfm.act(obs, np.ones(8, np.float32))


@pytest.mark.parametrize("key, value, match", [
    ("qpos", np.zeros((31, 76)), r"qpos has shape \(31, 76\), expected \(32, 76\)"),
    ("next_obs", np.zeros((32, 357)), r"next_obs has shape \(32, 357\), expected \(32, 358\)"),
    ("next_obs", np.zeros((0, 358)), "next_obs has shape"),
    ("qvel", np.full((32, 75), np.nan), "qvel contains NaN"),
    ("qpos", np.roll(humanoid_states(32, seed=0)["qpos"], 1, axis=0), "not the observations of its qpos/qvel"),
])
def test_malformed_reward_buffer_is_named(bfm, key, value, match):
    buf = {**bfm.reward_buffer, key: value}
    if key == "next_obs" and len(value) == 0:
        buf = {k: v[:0] for k, v in buf.items()}
    bad = BFM(bfm.model, bfm.config, reward_buffer=buf)
    with pytest.raises(CheckpointError, match=match):
        bad.prompt.reward("jump-2")


def test_states_only_save_rebuilds_the_observations_and_prompts_alike(bfm, tmp_path):
    full, small = bfm.save(tmp_path / "full", half=True), bfm.save(tmp_path / "small", half=True, states_only=True)
    size = lambda p: (p / "reward_buffer.safetensors").stat().st_size  # noqa: E731
    assert size(small) < 0.45 * size(full)  # 151 of 509 values per state
    again = BFM.load(small)
    buf, orig = again.reward_buffer, bfm.reward_buffer
    assert buf["next_obs"].dtype == np.float32 and buf["next_obs"].shape == orig["next_obs"].shape
    np.testing.assert_allclose(buf["next_obs"], orig["next_obs"], atol=0.05, rtol=0.01)  # from float16 states
    z_small, z_full = again.prompt.reward("move-ego-0-0"), BFM.load(full).prompt.reward("move-ego-0-0")
    assert z_small @ z_full / (np.linalg.norm(z_small) * np.linalg.norm(z_full)) > 0.999


def test_save_and_load_round_trip(bfm, tmp_path):
    out = bfm.save(tmp_path / "copy")
    again = BFM.load(out)
    obs, z = np.random.default_rng(2).normal(size=(3, 358)), np.ones(8) * np.sqrt(1.0)
    np.testing.assert_array_equal(again.act(obs, z), bfm.act(obs, z))
    for k in ("next_obs", "qpos", "qvel"):
        np.testing.assert_array_equal(again.reward_buffer[k], bfm.reward_buffer[k])
    assert again.sequence_length == 4 and again.z_dim == 8


def test_saved_config_holds_paths_under_the_working_directory_relative(bfm, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("FBCPR_DATA", raising=False)
    cfg = copy.deepcopy(bfm.config)
    cfg.env.motions = str(tmp_path / "mine" / "clips")
    out = BFM(bfm.model, cfg, reward_buffer=bfm.reward_buffer).save("shared")
    assert yaml.safe_load((out / "config.yaml").read_text())["env"]["motions"] == "mine/clips"
    assert cfg.env.motions == str(tmp_path / "mine" / "clips")  # the model's own config is left as it was
    cfg.env.motions = str(tmp_path / "data" / "clips")  # the data directory (./data): named as the configs name it
    out = BFM(bfm.model, cfg, reward_buffer=bfm.reward_buffer).save("shared")
    assert yaml.safe_load((out / "config.yaml").read_text())["env"]["motions"] == "$FBCPR_DATA/clips"
    cfg.env.motions = "/elsewhere/clips"  # outside the working directory: nothing to make relative to
    out = BFM(bfm.model, cfg, reward_buffer=bfm.reward_buffer).save("shared")
    assert yaml.safe_load((out / "config.yaml").read_text())["env"]["motions"] == "/elsewhere/clips"


def test_run_directory_means_its_latest_checkpoint(ckpt, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(ckpt, run / "checkpoints" / "step_0000000100")
    (run / "checkpoints" / "latest").write_text("step_0000000100")
    assert BFM.load(run).z_dim == 8 and BFM.load(run / "checkpoints").z_dim == 8
    (run / "checkpoints" / "latest").write_text("step_0000000200")  # points at nothing
    with pytest.raises(CheckpointError, match="step_0000000200"):
        BFM.load(run)


def _hub_cache(root: Path, ckpt: Path, repo: str = "org/tiny-bfm") -> Path:
    """The huggingface_hub cache layout: models--org--name/{refs/main, snapshots/<sha>/...}."""
    repo_dir = root / ("models--" + repo.replace("/", "--"))
    snap = repo_dir / "snapshots" / SHA
    shutil.copytree(ckpt, snap)
    (repo_dir / "refs").mkdir()
    (repo_dir / "refs" / "main").write_text(SHA)
    return snap


@pytest.fixture
def offline(monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)  # read once at import time


def test_load_from_offline_hub_cache(bfm, ckpt, tmp_path, offline):
    _hub_cache(tmp_path, ckpt)
    hub = BFM.load("org/tiny-bfm", cache_dir=tmp_path)
    obs = np.random.default_rng(3).normal(size=(2, 358))
    np.testing.assert_array_equal(hub.act(obs, np.ones(8)), bfm.act(obs, np.ones(8)))
    assert hub.reward_buffer["next_obs"].shape == (32, 358)


def test_missing_repo_offline_is_a_clear_error(tmp_path, offline):
    with pytest.raises(CheckpointError, match="not in the local cache"):
        BFM.load("org/does-not-exist", cache_dir=tmp_path)


def test_missing_file_in_cached_repo_is_named(ckpt, tmp_path, offline):
    snap = _hub_cache(tmp_path, ckpt)
    (snap / "model.safetensors").unlink()
    with pytest.raises(CheckpointError, match="model.safetensors"):
        BFM.load("org/tiny-bfm", cache_dir=tmp_path)


def test_local_path_errors(tmp_path):
    with pytest.raises(CheckpointError, match="no such checkpoint directory"):
        BFM.load(tmp_path / "nope" / "deeper")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(CheckpointError, match="not a checkpoint directory"):
        BFM.load(tmp_path / "file.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CheckpointError, match="manifest.json"):
        BFM.load(tmp_path / "empty")


def test_save_for_hub_stages_card_and_files(bfm, tmp_path):
    folder = bfm.save_for_hub(tmp_path / "hub", metrics={"reward/jump-2": 0.125}, repo_id="me/bfm")
    names = {p.name for p in folder.iterdir()}
    assert {"model.safetensors", "config.yaml", "manifest.json", "reward_buffer.safetensors", "README.md"} <= names
    assert "trainer_state.safetensors" not in names
    card = (folder / "README.md").read_text()
    header = yaml.safe_load(card.split("---")[1])
    assert header["library_name"] == "fbcpr" and "reinforcement-learning" in header["tags"]
    assert "| reward/jump-2 | 0.125 |" in card and 'BFM.load("me/bfm")' in card
    cfg_block = card.split("```yaml")[1].split("```")[0]
    assert yaml.safe_load(cfg_block)["agent"]["seq_length"] == 4
    assert BFM.load(folder).z_dim == 8  # the staged folder is itself a loadable checkpoint
    assert "No evaluation metrics" in (bfm.save_for_hub(tmp_path / "bare") / "README.md").read_text()


def test_push_to_hub_uploads_the_staged_folder(bfm, monkeypatch):
    calls = {}

    def fake_create_repo(repo_id, **kw):
        calls["create"] = (repo_id, kw)

    def fake_upload_folder(*, repo_id, folder_path, **kw):  # the network call; record what would be sent
        folder = Path(folder_path)
        calls["upload"] = (repo_id, sorted(p.name for p in folder.iterdir()), (folder / "README.md").read_text())
        return "commit-info"

    monkeypatch.setattr(huggingface_hub, "create_repo", fake_create_repo)
    monkeypatch.setattr(huggingface_hub, "upload_folder", fake_upload_folder)
    assert bfm.push_to_hub("me/bfm", metrics={"tracking/success": 0.5}, private=True) == "commit-info"
    assert calls["create"] == ("me/bfm", {"token": None, "private": True, "exist_ok": True})
    repo, files, card = calls["upload"]
    assert repo == "me/bfm"
    assert files == ["README.md", "config.yaml", "manifest.json", "model.safetensors", "reward_buffer.safetensors"]
    assert "| tracking/success | 0.5 |" in card
    with pytest.raises(ValueError, match="not a Hugging Face repo id"):
        bfm.push_to_hub("no-owner")


def test_bfm_is_an_evaluation_agent(bfm):
    from fbcpr.eval.agents import Agent

    assert isinstance(bfm, Agent)
    assert bfm.goal_z(np.zeros(358, np.float32)).shape == (8,)
    assert bfm.track_z(np.zeros((5, 358), np.float32)).shape == (4, 8)
    manifest = json.loads((Path(bfm.source) / "manifest.json").read_text())
    assert manifest["model"]["z_dim"] == bfm.z_dim


def test_compact_save_keeps_a_float16_subsample_that_prompts(bfm, tmp_path):
    full = bfm.save(tmp_path / "full")
    small = bfm.save(tmp_path / "small", reward_samples=16, half=True)
    size = lambda p: (p / "reward_buffer.safetensors").stat().st_size  # noqa: E731
    assert size(small) < 0.3 * size(full)
    again = BFM.load(small)
    buf = again.reward_buffer
    assert buf["next_obs"].shape == (16, 358) and buf["next_obs"].dtype == np.float32
    orig = bfm.reward_buffer["qpos"]  # every kept row is one of the original rows, to float16 precision
    err = np.abs(buf["qpos"][:, None] - orig[None]).max(-1).min(1)
    assert err.max() < 2e-3 * np.abs(orig).max()
    z = again.prompt.reward(lambda obs, action, qpos, qvel: obs[:, 0])
    assert z.shape == (bfm.z_dim,) and np.isfinite(z).all()
    with pytest.raises(ValueError, match="reward_samples"):
        bfm.save(tmp_path / "bad", reward_samples=0)


def test_legacy_checkpoint_without_action_mapping_means_mid(ckpt, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(ckpt, old)
    cfg = yaml.safe_load((old / "config.yaml").read_text())
    assert cfg["env"].pop("action_mapping") == "rest"
    (old / "config.yaml").write_text(yaml.safe_dump(cfg))
    manifest = json.loads((old / "manifest.json").read_text())
    import hashlib
    data = (old / "config.yaml").read_bytes()
    manifest["files"]["config.yaml"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    (old / "manifest.json").write_text(json.dumps(manifest))
    assert BFM.load(old).action_mapping == "mid" and BFM.load(ckpt).action_mapping == "rest"


def test_a_missing_local_path_is_not_looked_up_on_the_hub(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    (tmp_path / "runs").mkdir()
    for spec in ("runs/small", "./small", "old.runs/small"):
        with pytest.raises(CheckpointError, match="no such checkpoint directory") as err:
            BFM.load(spec, cache_dir=tmp_path / "hf")
        assert "Hugging Face" not in str(err.value), spec
