"""VIRL from video on the humanoid: the plain renderer's frames, frames kept in the replay buffer, the reward on them,
and a short `fbcpr imitate` run with video input."""
import numpy as np
import pytest
import torch
import yaml
from typer.testing import CliRunner

from fbcpr.cli.app import app
from fbcpr.core.errors import ConfigError
from fbcpr.rewards.virl.config import VIRLConfig
from fbcpr.rewards.virl.frames import render_clip
from fbcpr.rewards.virl.reward import VIRLReward
from fbcpr.train.buffer import ReplayBuffer, transition_specs
from humanoid_env.model import default_qpos, load_model
from humanoid_env.render import TrackRenderer, renderer_available
from motions.clip import from_qpos, save_clip
from motions.library import MotionLibrary

torch.set_num_threads(1)
SMALL = dict(embed_dim=16, hidden_dim=32, lr=3e-3)
needs_gl = pytest.mark.skipif(not renderer_available(), reason="no OpenGL renderer in this process (MUJOCO_GL)")


def arm_rise(frames: int = 12):
    """The default standing pose raising one arm: a short clip whose frames differ."""
    qpos = np.tile(default_qpos(), (frames, 1))
    qpos[:, 7 + 45] = np.linspace(0.0, 1.2, frames)
    return from_qpos(qpos, name="arm_rise")


@needs_gl
def test_plain_frame_shows_the_body_where_the_default_render_does():
    model = load_model()
    TrackRenderer(model, 16, 16, plain=True).close()
    assert model.vis.quality.shadowsize > 0 and model.vis.quality.offsamples > 0  # the caller's model is left alone
    plain, default = (render_clip(default_qpos()[None], 64, plain=p)[0] for p in (True, False))
    body = plain > 0.3                                   # the body is lit grey; floor and plain sky are darker
    rows, cols = body.nonzero()
    assert body.sum() >= 20 and rows.max() - rows.min() >= 20          # a standing figure, not a speck
    assert 16 <= cols.min() and cols.max() < 48                        # in the middle: the camera tracks it
    assert plain[:8].max() < 0.1 < default[:8].max()                   # no skybox in the plain frame
    assert (default[body] > 0.3).mean() > 0.5        # most of them lit in the default render too (shading differs)


@needs_gl
def test_humanoid_video_reward_fits_and_rewards_stored_frames():
    clip = arm_rise()
    cfg = VIRLConfig(input="video", image_size=16, seq_length=3, **SMALL)
    virl = VIRLReward(clip.obs.shape[1], cfg, seed=0, library=MotionLibrary([clip]))
    assert virl.frame_size == 16 and virl.frames is not None and virl.frames.shape == (10, 3, 2, 16, 16)
    demo = torch.as_tensor(render_clip(clip.qpos, 16) * 255).round().to(torch.uint8).unfold(0, 3, 1).movedim(-1, 1)
    n = len(demo)
    obs = torch.as_tensor(clip.obs[:n])
    noise = torch.randint(0, 256, demo.shape, dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    metrics = virl.fit(torch.zeros(4, 3, obs.shape[1]), {"obs": obs, "next_obs": obs, "frames": noise})
    assert all(np.isfinite(v) for v in metrics.values())
    own = virl.reward(obs, obs, frames=demo)
    torch.testing.assert_close(own, torch.ones(n), rtol=0, atol=1e-4)           # its own windows: distance 0
    assert (virl.reward(obs, obs, frames=noise) < 0.999).all()
    with pytest.raises(ValueError, match="frames"):
        virl.reward(obs, obs)
    with pytest.raises(ConfigError, match="agent.virl.multitask"):
        VIRLReward(clip.obs.shape[1], VIRLConfig(input="video", multitask="synthetic"), library=MotionLibrary([clip]))


def test_buffer_frames_follow_the_history_walk_and_stay_uint8():
    n_env = 2
    specs = transition_specs(1, 1, 0, 1, 1) | {"frame": (2, 2)}
    buf = ReplayBuffer(30, specs, stride=n_env)
    obs = np.array([[0.0], [100.0]], np.float32)
    for _ in range(5):
        nxt = obs + 1
        buf.add({"obs": obs, "action": np.zeros((n_env, 1)), "next_obs": nxt, "z": np.zeros((n_env, 0)),
                 "qpos": np.zeros((n_env, 1)), "qvel": np.zeros((n_env, 1)), "terminated": np.zeros(n_env),
                 "frame": np.broadcast_to(nxt[:, :, None] % 256, (n_env, 2, 2))})  # frame value = s' value
        obs = nxt
    out = buf.sample(np.random.default_rng(0), 50, fields=("obs", "next_obs"), history=2, frames=True)
    frames, hist = out["frames"], out["history"][..., 0]
    assert frames.dtype == torch.uint8 and frames.shape == (50, 3, 2, 2)
    first = out["obs"][:, 0] % 100 == 0                                              # reset states have no frame
    assert (frames[:, -1, 0, 0].float() == out["next_obs"][:, 0]).all()            # the last frame is s'
    assert (frames[~first, 1, 0, 0].float() == hist[~first, 1]).all()              # then s, as the history
    assert (frames[first, 0] == frames[first, 2]).all() and first.any() and (~first).any()
    with pytest.raises(ValueError, match="frame"):
        ReplayBuffer(4, transition_specs(1, 1, 0, 1, 1)).sample(np.random.default_rng(0), 1, history=1, frames=True)


@needs_gl
def test_imitate_with_video_input_writes_a_checkpoint(tmp_path):
    path = save_clip(arm_rise(), tmp_path / "arm_rise.npz")
    cfg = {"algorithm": "td3", "model": {"hidden_dim": 32, "hidden_layers": 1},
           "agent": {"batch_size": 16, "seq_length": 4, "reward": {"imitation": "virl"},
                     "virl": {"input": "video", "image_size": 16, "seq_length": 3, **SMALL}},
           "env": {"name": "humanoid", "max_episode_steps": 20},
           "train": {"num_envs": 2, "warmup_steps": 16, "rollout_steps": 16, "updates_per_rollout": 2,
                     "buffer_capacity": 200, "eval_every": 0, "priority_every": 0, "checkpoint_every": 32,
                     "log_every": 16, "reward_buffer_size": 0, "torch_threads": 1}}
    (tmp_path / "video.yaml").write_text(yaml.safe_dump(cfg))
    res = CliRunner().invoke(app, ["imitate", str(path), "--reward", "virl", "--config", str(tmp_path / "video.yaml"),
                                   "--out", str(tmp_path / "r"), "--steps", "48", "--no-progress"],
                             env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r" / "checkpoints" / "latest").is_file()
    assert "virl/seq_loss" in (tmp_path / "r" / "metrics.csv").read_text()
