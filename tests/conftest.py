"""Test-session setup. MuJoCo reads MUJOCO_GL once, at its first import, so set the headless backend before any
test module imports mujoco (humanoid_env does the same for users, but test collection order is not fixed)."""
import os
import signal

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler for the test, then whatever was there: a runner started as a background job
    inherits SIGINT ignored, and tests of stop signals check that our handler is swapped back for the default."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.fixture(scope="session")
def two_clips(tmp_path_factory):
    """A clip folder as `fbcpr motions import` writes it, with two short synthetic clips (stand, t-pose): enough for
    a humanoid run that needs MoCap starts and expert windows, without importing the synthetic library (it needs
    scipy) in the run."""
    from motions import synthetic
    from motions.clip import save_clip

    folder = tmp_path_factory.mktemp("clips")
    for clip in (synthetic.stand(1.0), synthetic.tpose(1.0)):
        save_clip(clip, folder / f"{clip.name}.npz")
    return folder


def humanoid_states(n: int, seed: int, drop: tuple[float, float] = (-0.8, 0.3)) -> dict:
    """n standing-ish random humanoid states and their observations, row by row: a stand-in for a reward-inference
    buffer (whose rows must each be one state's, as loading checks)."""
    import numpy as np

    from humanoid_env.model import NV, load_model
    from humanoid_env.observation import observe

    m = load_model()
    rng = np.random.default_rng(seed)
    qpos = np.tile(m.qpos0, (n, 1))
    qpos[:, 7:] = np.clip(rng.normal(0.0, 0.3, (n, 69)), m.jnt_range[1:, 0], m.jnt_range[1:, 1])
    qpos[:, 2] += rng.uniform(*drop, n)
    qvel = rng.normal(0.0, 1.0, (n, NV))
    return {"next_obs": observe(m, qpos, qvel), "qpos": qpos, "qvel": qvel}


def tiny_humanoid_checkpoint(root, name: str, seed: int, preset: str = "tiny", mapping: str = "rest"):
    """An untrained FB-CPR inference checkpoint for the humanoid at root/name, with 32 reward states and a fitted
    normaliser: distinct weights per seed, for tests of what works on whole models."""
    import torch

    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    torch.manual_seed(seed)
    cfg = config_from_dict({"model": {"preset": preset, "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8},
                            "env": {"name": "humanoid", "action_mapping": mapping}})
    model = FBCPRModel(cfg.model)
    buf = humanoid_states(32, seed=seed)
    model.obs_normalizer.update(torch.as_tensor(buf["next_obs"]))
    return save_checkpoint(root / name, model, cfg, reward_buffer=buf)


def toy_run_config(algorithm: str = "fb_cpr", model: dict | None = None, agent: dict | None = None,
                   train: dict | None = None):
    """A tiny training config on the toy env for trainer tests: 4 envs, 30-step episodes, a 40-step warm-up, no
    evaluation or periodic checkpoint, one torch thread. Each section's keys override these."""
    from fbcpr.core.config import config_from_dict

    return config_from_dict({
        "algorithm": algorithm,
        "model": {"preset": "tiny", **(model or {})},
        "agent": {"batch_size": 32, **(agent or {})},
        "env": {"name": "toy", "max_episode_steps": 30},
        "train": {"total_env_steps": 100_000, "num_envs": 4, "warmup_steps": 40, "rollout_steps": 20,
                  "updates_per_rollout": 2, "buffer_capacity": 1000, "priority_every": 0, "eval_every": 0,
                  "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 0, "torch_threads": 1,
                  **(train or {})},
    })
