"""NPMP reuse (fbcpr.apps.npmp.reuse): the latent action space, the AR(1) prior mapping, checkpoint and config errors,
and TD3 training end to end in an NPMP's latent space on the toy."""
import json
import math

import numpy as np
import pytest
import torch

from fbcpr.core.config import config_from_dict, load_config
from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import EnvConfig
from fbcpr.envs.bundle import make_env
from fbcpr.apps.npmp.checkpoint import save_npmp
from fbcpr.apps.npmp.config import npmp_config
from fbcpr.apps.npmp.model import NPMPModel
from fbcpr.apps.npmp.reuse import LatentActionEnv, load_decoder, task_return
from fbcpr.envs import toy as pm
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)
ALPHA = 0.9


def toy_npmp(obs_dim: int = pm.OBS_DIM, action_dim: int = pm.ACTION_DIM) -> NPMPModel:
    torch.manual_seed(0)
    return NPMPModel(npmp_config({"alpha": ALPHA}, preset="tiny"), obs_dim, action_dim).eval()


@pytest.fixture
def npmp_dir(tmp_path):
    return save_npmp(tmp_path / "npmp", toy_npmp(), {"method": "lfpc", "expert": "test"})


def test_action_and_observation_spaces():
    model = toy_npmp()
    env = LatentActionEnv(pm.PointMassVectorEnv(3), model, scale=1.5)
    d = model.z_dim
    assert env.single_action_space.shape == (d,) and env.action_space.shape == (3, d)
    assert np.all(env.single_action_space.low == -1) and np.all(env.single_action_space.high == 1)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (3, pm.OBS_DIM + d) and env.observation_space.shape == (3, pm.OBS_DIM + d)
    np.testing.assert_array_equal(obs[:, pm.OBS_DIM:], 0.0)  # every episode starts at the prior's mode
    np.testing.assert_array_equal(obs[:, :pm.OBS_DIM], env.unwrapped.qpos.astype(np.float32))


def test_prior_mapping_and_decoded_actions():
    model = toy_npmp()
    env = LatentActionEnv(pm.PointMassVectorEnv(2), model, scale=2.0)
    obs, _ = env.reset(seed=0)
    z_prev = np.array([[1.0, -2.0, 0.5, 0.0], [0.3, 0.3, -1.0, 2.0]], np.float32)
    env.z = z_prev.copy()
    pos = obs[:, :pm.OBS_DIM].copy()
    obs, _, _, _, info = env.step(np.zeros((2, model.z_dim), np.float32))  # eps = 0: z_t = alpha z_{t-1}
    np.testing.assert_allclose(obs[:, pm.OBS_DIM:], ALPHA * z_prev, rtol=1e-6)
    expected = model.act(torch.as_tensor(pos), torch.as_tensor(ALPHA * z_prev)).numpy()
    np.testing.assert_allclose(info["env_action"], expected, atol=1e-6)
    np.testing.assert_allclose(obs[:, :pm.OBS_DIM], np.clip(pos + pm.STEP * expected, -1, 1), atol=1e-6)
    a = np.array([[1.0, -1.0, 0.5, 3.0], [0.0, 0.25, -0.5, -7.0]], np.float32)  # beyond [-1, 1]: clipped
    z1 = obs[:, pm.OBS_DIM:].copy()
    obs, *_ = env.step(a)
    want = ALPHA * z1 + math.sqrt(1 - ALPHA**2) * 2.0 * np.clip(a, -1, 1)
    np.testing.assert_allclose(obs[:, pm.OBS_DIM:], want, rtol=1e-5, atol=1e-6)


def test_episode_end_resets_the_latent():
    model = toy_npmp()
    env = LatentActionEnv(pm.PointMassVectorEnv(2, max_episode_steps=2), model, scale=1.0)
    env.reset(seed=0)
    a = np.ones((2, model.z_dim), np.float32)
    obs, *_ = env.step(a)
    z1 = obs[:, pm.OBS_DIM:]
    assert np.abs(z1).min() > 0
    obs, _, _, truncated, info = env.step(a)
    assert truncated.all()
    np.testing.assert_allclose(info["final_obs"][:, pm.OBS_DIM:], ALPHA * z1 + math.sqrt(1 - ALPHA**2) * a, rtol=1e-5)
    np.testing.assert_array_equal(obs[:, pm.OBS_DIM:], 0.0)
    with pytest.raises(ValueError, match="actions"):
        env.step(np.ones((2, model.z_dim + 1), np.float32))


def test_bundle_dims_and_task_reward(npmp_dir):
    raw = make_env(EnvConfig(name="toy"), 2, 0)
    bundle = make_env(EnvConfig(name="toy", npmp=str(npmp_dir)), 2, 0)
    d = toy_npmp().z_dim
    assert (bundle.obs_dim, bundle.action_dim) == (raw.obs_dim + d, d)
    obs = np.array([[0.6, 0.6, 5.0, 5.0, 5.0, 5.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]], np.float32)
    r = bundle.task_reward("reach-top-right")(obs, obs[:, :2], np.zeros((2, 2)))
    np.testing.assert_allclose(r, raw.task_reward("reach-top-right")(obs[:, :2], obs[:, :2], np.zeros((2, 2))))
    out = task_return(lambda o: np.zeros((len(o), d), np.float32), bundle, "reach-top-right", episodes=3, steps=5)
    assert 0.0 <= out["return"] <= 5.0 and out["action_change"] >= 0.0


def test_bad_checkpoints_are_config_errors(tmp_path, npmp_dir):
    with pytest.raises(ConfigError, match="env.npmp.*cannot load"):
        make_env(EnvConfig(name="toy", npmp=str(tmp_path / "missing")), 2, 0)
    (npmp_dir / "model.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ConfigError, match="env.npmp.*cannot load"):
        make_env(EnvConfig(name="toy", npmp=str(npmp_dir)), 2, 0)
    wide = save_npmp(tmp_path / "wide", toy_npmp(obs_dim=3), {"method": "bc"})
    with pytest.raises(ConfigError, match="env.npmp.*obs_dim 3.*toy env has 2"):
        make_env(EnvConfig(name="toy", npmp=str(wide)), 2, 0)


def test_action_mapping_must_match(tmp_path):
    path = save_npmp(tmp_path / "mid", toy_npmp(), {"method": "bc", "action_mapping": "mid"})
    toy = make_env(EnvConfig(name="toy"), 1, 0)  # toy-sized dims; the mapping check is the humanoid's
    with pytest.raises(ConfigError, match="env.npmp.*'mid'.*env.action_mapping is 'rest'"):
        load_decoder(str(path), toy, EnvConfig(name="humanoid", action_mapping="rest"))
    assert load_decoder(str(path), toy, EnvConfig(name="humanoid", action_mapping="mid")).z_dim == 4


def test_config_rules(tmp_path, npmp_dir):
    with pytest.raises(ConfigError, match="env.npmp: acting through"):
        config_from_dict({"env": {"name": "toy", "npmp": str(npmp_dir)}})
    with pytest.raises(ConfigError, match="env.npmp: acting through"):
        config_from_dict({"algorithm": "td3", "agent": {"reward": {"task": "reach-top-right", "imitation": "amp"}},
                          "env": {"name": "toy", "npmp": str(npmp_dir)}})
    with pytest.raises(ConfigError, match="env.npmp_innovation_scale"):
        config_from_dict({"algorithm": "td3", "agent": {"reward": {"task": "reach-top-right"}},
                          "env": {"name": "toy", "npmp": "x", "npmp_innovation_scale": 0.0}})
    yaml_file = tmp_path / "sub" / "run.yaml"
    yaml_file.parent.mkdir()
    yaml_file.write_text(json.dumps({"algorithm": "td3", "agent": {"reward": {"task": "ring"}},
                                     "env": {"name": "toy", "npmp": "../npmp"}}))
    assert load_config(yaml_file).env.npmp == str(npmp_dir.resolve())  # relative to the config's folder


def test_td3_trains_in_latent_space(tmp_path, npmp_dir):
    cfg = config_from_dict({
        "algorithm": "td3", "model": {"hidden_dim": 16, "hidden_layers": 1},
        "agent": {"batch_size": 32, "reward": {"task": "reach-top-right"}},
        "env": {"name": "toy", "max_episode_steps": 30, "npmp": str(npmp_dir)},
        "train": {"total_env_steps": 200, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                  "updates_per_rollout": 2, "buffer_capacity": 1000, "priority_every": 0, "eval_every": 100,
                  "checkpoint_every": 0, "log_every": 100, "reward_buffer_size": 0, "torch_threads": 1}})
    evals = []
    trainer = Trainer(cfg, tmp_path / "run", progress=False,
                      evaluate=lambda agent: evals.append(agent.model.act(np.zeros((1, 6), np.float32))) or {"x": 1.0})
    summary = trainer.run()
    trainer.close()
    d = toy_npmp().z_dim
    assert summary["env_steps"] == 200 and summary["updates"] > 0 and len(evals) == 2
    assert trainer.agent.model.cfg.action_dim == d and trainer.agent.model.cfg.obs_dim == pm.OBS_DIM + d
    batch = trainer.buffer.sample(np.random.default_rng(0), 64, fields=("obs", "action", "next_obs"))
    assert batch["action"].shape == (64, d) and batch["obs"].shape == (64, pm.OBS_DIM + d)
    assert torch.isfinite(batch["next_obs"]).all() and (batch["next_obs"][:, pm.OBS_DIM:] != 0).any()
    assert (tmp_path / "run" / "checkpoints" / "latest").exists()
