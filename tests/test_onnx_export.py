"""`fbcpr export CKPT OUT --onnx`: the actor and B in onnxruntime answer as torch does, the JSON holds what an app
needs (sizes, the action mapping, the stored prompts), and the shipped model walks the same under either."""
from __future__ import annotations

import json
import sys

import numpy as np
import onnxruntime as ort
import pytest
import torch
from typer.testing import CliRunner

from fbcpr.cli.app import app
from fbcpr.inference.bfm import BFM
from humanoid_env.actions import ActionMap
from humanoid_env.env import HumanoidEnv
from humanoid_env.model import load_model

torch.set_num_threads(1)
runner = CliRunner()
WALK = "move-ego-0-2"


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("onnx") / "pretrained-onnx"
    result = runner.invoke(app, ["export", "pretrained", str(out), "--onnx"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def bfm():
    return BFM.load("pretrained")


def session(path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def test_actor_and_backward_match_torch_on_1000_random_inputs(exported, bfm):
    rng = np.random.default_rng(0)
    norm = bfm.model.obs_normalizer
    # observations spread around the training statistics (3 std), and z's of any norm: the graph projects them
    obs = (norm.mean.numpy() + 3 * np.sqrt(norm.var.numpy()) * rng.standard_normal((1000, bfm.obs_dim)))
    obs = obs.astype(np.float32)
    z = (rng.standard_normal((1000, bfm.z_dim)) * rng.uniform(0.1, 10, (1000, 1))).astype(np.float32)
    action = session(exported / "actor.onnx").run(["action"], {"obs": obs, "z": z})[0]
    embedding = session(exported / "backward.onnx").run(["embedding"], {"obs": obs})[0]
    want_action, want_b = bfm.act(obs, z), bfm.backward(obs)
    assert action.shape == (1000, bfm.action_dim) and embedding.shape == (1000, bfm.z_dim)
    assert np.abs(action - want_action).max() < 1e-5
    assert np.abs(embedding - want_b).max() < 1e-5
    assert np.abs(want_action).max() > 0.5 and np.std(want_b) > 0.1  # the comparison is on outputs that vary


def test_json_holds_sizes_mapping_and_stored_prompts(exported, bfm):
    meta = json.loads((exported / "fbcpr-onnx.json").read_text())
    assert (meta["obs_dim"], meta["action_dim"], meta["z_dim"]) == (358, 69, 64)
    assert meta["control_hz"] == 30 and meta["actor"]["file"] == "actor.onnx"
    amap = ActionMap(load_model(), bfm.action_mapping)
    mapping = meta["action_mapping"]
    assert mapping["name"] == bfm.action_mapping and len(mapping["joints"]) == 69
    action = np.linspace(-1, 1, 69)
    # the rule the JSON states, applied with its arrays, gives the env's PD targets
    target = np.asarray(mapping["center"]) + action * np.where(action >= 0, mapping["up"], mapping["down"])
    np.testing.assert_allclose(target, amap.to_ctrl(action), atol=1e-12)
    assert set(meta["prompts"]) == set(bfm.reward_prompts.z) and len(meta["prompts"]) == 54
    np.testing.assert_allclose(meta["prompts"][WALK], bfm.prompt.reward(WALK), atol=1e-7)
    assert set(meta["refined_prompts"]) == set(bfm.reward_prompts.refined)


def walk_return(act, z: np.ndarray, seed: int, steps: int = 300) -> float:
    env = HumanoidEnv(action_mapping=BFM.load("pretrained").action_mapping, reward=WALK, max_episode_steps=steps)
    obs, _ = env.reset(seed=seed)
    total = 0.0
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(act(obs, z))
        total += reward
        if terminated or truncated:
            break
    return total


def test_onnx_actor_walks_as_torch_does(exported, bfm):
    meta = json.loads((exported / "fbcpr-onnx.json").read_text())
    z = np.asarray(meta["prompts"][WALK], dtype=np.float32)
    actor = session(exported / "actor.onnx")
    onnx_return = walk_return(lambda o, zz: actor.run(None, {"obs": o[None], "z": zz[None]})[0][0], z, seed=0)
    torch_return = walk_return(bfm.act, z, seed=0)
    assert torch_return > 100  # it walks: move-ego-0-2 pays up to 1 per step, 300 steps
    assert abs(onnx_return - torch_return) <= 0.05 * torch_return


def test_onnx_replaces_an_earlier_export_and_refuses_other_folders(exported, tmp_path):
    again = runner.invoke(app, ["export", "pretrained", str(exported), "--onnx"])
    assert again.exit_code == 0, again.output
    (tmp_path / "notes.txt").write_text("mine")
    refused = runner.invoke(app, ["export", "pretrained", str(tmp_path), "--onnx"])
    assert refused.exit_code == 1 and "no fbcpr-onnx.json" in refused.output
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_onnx_rejects_checkpoint_storage_options(tmp_path):
    result = runner.invoke(app, ["export", "pretrained", str(tmp_path / "o"), "--onnx", "--full"])
    assert result.exit_code == 1 and "--half" in result.output and "writes no checkpoint" in result.output


def test_missing_onnx_extra_names_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import onnxruntime now raises ImportError
    result = runner.invoke(app, ["export", "pretrained", str(tmp_path / "o"), "--onnx"])
    assert result.exit_code == 1
    assert 'pip install "fbcpr[onnx]"' in result.output and len(result.output.strip().splitlines()) <= 2
