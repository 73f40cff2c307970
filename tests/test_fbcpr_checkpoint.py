"""Checkpoints: round trip, no unpickling, named errors on corruption/mismatch, atomic replacement."""
import json
import os
import pickle

import numpy as np
import pytest
import torch

import fbcpr.core.checkpoint as ckpt_mod
from fbcpr.core.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel

torch.set_num_threads(1)


def make(z_dim=8, seed=0):
    torch.manual_seed(seed)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3, "z_dim": z_dim}})
    model = FBCPRModel(cfg.model)
    model.obs_normalizer.update(torch.randn(20, 6) * 3)
    return cfg, model


def reward_buffer(n=5):
    return {"next_obs": np.random.randn(n, 6), "qpos": np.random.randn(n, 4), "qvel": np.random.randn(n, 3)}


def same_weights(a, b):
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def test_roundtrip_without_unpickling(tmp_path, monkeypatch):
    cfg, model = make()
    rb = reward_buffer()
    save_checkpoint(tmp_path / "c", model, cfg, trainer_state=({"x": torch.arange(3)}, {"step": 7}), reward_buffer=rb)
    assert sorted(os.listdir(tmp_path / "c")) == ["config.yaml", "manifest.json", "model.safetensors",
                                                  "reward_buffer.safetensors", "trainer_state.safetensors"]

    def forbidden(*a, **k):
        raise AssertionError("unpickling during checkpoint load")
    monkeypatch.setattr(torch, "load", forbidden)
    monkeypatch.setattr(pickle, "load", forbidden)
    monkeypatch.setattr(pickle, "loads", forbidden)
    c = load_checkpoint(tmp_path / "c")
    assert same_weights(c.model, model) and c.config == cfg
    tensors, meta = c.trainer_state()
    assert meta == {"step": 7} and torch.equal(tensors["x"], torch.arange(3))
    np.testing.assert_allclose(c.reward_buffer()["qpos"], rb["qpos"].astype(np.float32))
    manifest = json.loads((tmp_path / "c" / "manifest.json").read_text())
    assert manifest["model"] == {"obs_dim": 6, "action_dim": 3, "z_dim": 8}
    assert manifest["tensors"]["model.safetensors"]["backward_map.net.layers.0.weight"] == [1, 6, 32]
    obs, z = torch.randn(4, 6), model.sample_z(4)
    torch.testing.assert_close(c.model.act(obs, z), model.act(obs, z), rtol=0, atol=0)


def test_corrupted_file_is_named(tmp_path):
    cfg, model = make()
    save_checkpoint(tmp_path / "c", model, cfg)
    p = tmp_path / "c" / "model.safetensors"
    raw = bytearray(p.read_bytes())
    raw[-10] ^= 0xFF
    p.write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match=r"model\.safetensors: checksum mismatch"):
        load_checkpoint(tmp_path / "c")


def test_truncated_and_missing_files(tmp_path):
    cfg, model = make()
    save_checkpoint(tmp_path / "c", model, cfg)
    (tmp_path / "c" / "model.safetensors").write_bytes(b"\x00" * 10)
    with pytest.raises(CheckpointError, match="model.safetensors"):
        load_checkpoint(tmp_path / "c")
    (tmp_path / "c" / "manifest.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="manifest.json: invalid JSON"):
        load_checkpoint(tmp_path / "c")
    os.remove(tmp_path / "c" / "manifest.json")
    with pytest.raises(CheckpointError, match="manifest.json: missing"):
        load_checkpoint(tmp_path / "c")
    with pytest.raises(CheckpointError, match="not a checkpoint directory"):
        load_checkpoint(tmp_path / "nowhere")


def test_config_mismatch_names_the_tensor(tmp_path):
    cfg16, _ = make(z_dim=16)
    _, model8 = make(z_dim=8)
    save_checkpoint(tmp_path / "c", model8, cfg16)  # weights of a d=8 model under a d=16 config
    with pytest.raises(CheckpointError, match=r"tensor '.*' has shape .* config expects"):
        load_checkpoint(tmp_path / "c")


def test_nan_weights_rejected(tmp_path):
    cfg, model = make()
    with torch.no_grad():
        model.actor.head.layers[0].weight[0, 0, 0] = float("nan")
    save_checkpoint(tmp_path / "c", model, cfg)
    with pytest.raises(CheckpointError, match="NaN"):
        load_checkpoint(tmp_path / "c")


def test_crash_mid_save_keeps_previous_checkpoint(tmp_path, monkeypatch):
    cfg, old = make(seed=0)
    _, new = make(seed=1)
    save_checkpoint(tmp_path / "c", old, cfg)
    real = ckpt_mod.write_tensors

    def crash(path, tensors, meta=None):
        real(path, tensors, meta)
        if path.name == "reward_buffer.safetensors":
            raise OSError("disk full (simulated)")
    monkeypatch.setattr(ckpt_mod, "write_tensors", crash)
    with pytest.raises(OSError, match="simulated"):
        save_checkpoint(tmp_path / "c", new, cfg, reward_buffer=reward_buffer())
    assert os.listdir(tmp_path) == ["c"]  # temp dir cleaned up
    assert same_weights(load_checkpoint(tmp_path / "c").model, old)


def test_crash_between_renames_falls_back_to_previous(tmp_path, monkeypatch):
    cfg, old = make(seed=0)
    _, new = make(seed=1)
    save_checkpoint(tmp_path / "c", old, cfg)
    real_rename, calls = os.rename, []

    def rename(src, dst):
        calls.append(dst)
        if len(calls) == 2:  # old -> backup done; crash before tmp -> path
            raise KeyboardInterrupt("killed (simulated)")
        real_rename(src, dst)
    monkeypatch.setattr(ckpt_mod.os, "rename", rename)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(tmp_path / "c", new, cfg)
    monkeypatch.setattr(ckpt_mod.os, "rename", real_rename)
    assert same_weights(load_checkpoint(tmp_path / "c").model, old)
    save_checkpoint(tmp_path / "c", new, cfg)  # the next save completes normally
    assert same_weights(load_checkpoint(tmp_path / "c").model, new)
    assert sorted(os.listdir(tmp_path)) == ["c"]


def test_checkpoint_files_follow_the_umask(tmp_path):
    """safetensors writes its files 0600; a checkpoint's files get the permissions the umask gives (0644 here)."""
    cfg, model = make()
    old = os.umask(0o022)
    try:
        path = save_checkpoint(tmp_path / "ck", model, cfg, reward_buffer=reward_buffer())
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in path.iterdir()}
    assert {"model.safetensors", "reward_buffer.safetensors"} <= set(modes)
    assert set(modes.values()) == {0o644}, modes
