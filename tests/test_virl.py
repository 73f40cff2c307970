"""VIRL: the comparator's losses and distances, its reward, frames, config errors, state, and the buffer's history."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from fbcpr.train.buffer import ReplayBuffer, transition_specs
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import ImitationReward
from fbcpr.envs import toy as pm
from fbcpr.rewards.virl.config import VIRLConfig
from fbcpr.rewards.virl.frames import load_frames, rasterize_points, save_frames
from fbcpr.rewards.virl.losses import make_pairs, virl_loss
from fbcpr.rewards.virl.model import Comparator, distance
from fbcpr.rewards.virl.reward import VIRLReward, windows_of

torch.set_num_threads(1)
SMALL = dict(embed_dim=16, hidden_dim=32, lr=3e-3)
L = 6


def demo_windows() -> torch.Tensor:
    return windows_of(torch.as_tensor(pm.demo_paths()["circle-ccw"]), L)[::4]             # (49, 6, 2)


def still_batch(n: int = 64) -> dict[str, torch.Tensor]:
    """An agent that stands still at random places: its sequences are one state repeated."""
    s = torch.rand(n, 2, generator=torch.Generator().manual_seed(1)) * 2 - 1
    return {"obs": s, "next_obs": s, "history": s[:, None].expand(-1, L - 1, -1)}


def trained(steps: int = 120, **kw) -> VIRLReward:
    virl = VIRLReward(2, VIRLConfig(seq_length=L, **SMALL, **kw), seed=0)
    w, batch = demo_windows(), still_batch()
    for i in range(steps):
        virl.fit(w[(torch.arange(16) + 16 * i) % len(w)], batch)
    return virl


def test_contrastive_training_separates_positive_from_negative_pairs():
    virl = VIRLReward(2, VIRLConfig(seq_length=L, **SMALL), seed=0)
    w, batch = demo_windows(), still_batch()
    first = virl.fit(w[:16], batch)
    for i in range(60):
        last = virl.fit(w[(torch.arange(16) + 16 * i) % len(w)], batch)
    assert last["virl/seq_loss"] < 0.7 * first["virl/seq_loss"], (first, last)
    assert last["virl/d_neg"] > last["virl/d_pos"] + 0.3, last


def test_distance_zero_for_identical_symmetric_and_larger_when_shuffled():
    virl = trained()
    w = demo_windows()[:20]
    e, h = virl.model.encode(virl._inputs(w))
    assert torch.allclose(distance(h, h), torch.zeros(len(w)))
    shuffled = w[:, torch.randperm(L, generator=torch.Generator().manual_seed(0))]
    _, hs = virl.model.encode(virl._inputs(shuffled))
    torch.testing.assert_close(distance(h, hs), distance(hs, h))
    assert (virl.distance(shuffled) > virl.distance(w)).float().mean() > 0.8


def test_reward_prefers_the_demo_to_shuffled_and_still_rollouts_batched_and_finite():
    virl = trained()
    assert isinstance(virl, ImitationReward) and virl.history == L - 1
    w = demo_windows()[:30]
    order = torch.randperm(L, generator=torch.Generator().manual_seed(2))
    shuffled = w[:, order]
    r_demo = virl.reward(w[:, -2], w[:, -1], history=w[:, :-1])
    r_shuf = virl.reward(shuffled[:, -2], shuffled[:, -1], history=shuffled[:, :-1])
    b = still_batch(30)
    r_still = virl.reward(b["obs"], b["next_obs"], history=b["history"])
    assert r_demo.shape == r_shuf.shape == (30,) and torch.isfinite(torch.cat([r_demo, r_shuf, r_still])).all()
    assert r_demo.mean() > r_shuf.mean() + 0.03 and r_demo.mean() > r_still.mean() + 0.5, (r_demo, r_shuf, r_still)


def test_encoders_give_the_documented_shapes_and_frames_their_range(tmp_path):
    state = VIRLReward(358, VIRLConfig(**SMALL))
    x = state._inputs(torch.randn(3, 5, 358))                                               # states and their steps
    e, h = state.model.encode(x)
    assert x.shape == (3, 5, 716) and e.shape == (3, 5, 16) and h.shape == (3, 16)
    assert state.model.decode_sequence(h, 5).shape == (3, 5, 716)
    assert Comparator(358, VIRLConfig(motion=False, **SMALL)).encode(torch.randn(3, 5, 358))[1].shape == (3, 16)
    video = VIRLReward(2, VIRLConfig(input="video", image_size=64, **SMALL))
    path = torch.as_tensor(pm.demo_paths()["circle-ccw"][:5])[None]
    frames = rasterize_points(path, 64)
    assert frames.shape == (1, 5, 64, 64) and frames.min() >= 0 and frames.max() <= 1 and frames.max() > 0.9
    x = video._inputs(path)                                                                 # frame + difference
    assert x.shape == (1, 5, 2, 64, 64) and torch.equal(x[:, :, 0], frames) and not x[0, 0, 1].any()
    e, h = video.model.encode(x)
    assert e.shape == (1, 5, 16) and video.model.decode_frames(e).shape == (1, 5, 2, 64, 64)
    back = load_frames(save_frames(frames[0].numpy(), tmp_path / "demo"), 32)             # a folder of PNGs
    assert back.shape == (5, 32, 32) and back.dtype == np.float32 and 0 <= back.min() and back.max() <= 1
    with pytest.raises(ValueError, match="not a folder"):
        load_frames(tmp_path / "missing", 32)


def test_video_reward_runs_on_rendered_toy_frames_and_a_frames_folder(tmp_path):
    folder = save_frames(rasterize_points(torch.as_tensor(pm.demo_paths()["circle-ccw"][:40]), 32).numpy(),
                         tmp_path / "frames")
    for cfg in (VIRLConfig(input="video", image_size=32, seq_length=L, **SMALL),
                VIRLConfig(input="video", image_size=32, seq_length=L, demo_frames=str(folder), **SMALL)):
        virl = VIRLReward(2, cfg, seed=0)
        metrics = virl.fit(demo_windows()[:8], still_batch(8))
        assert all(np.isfinite(v) for v in metrics.values())
        b = still_batch(4)
        r = virl.reward(b["obs"], b["next_obs"], history=b["history"])
        assert r.shape == (4,) and torch.isfinite(r).all()


def test_config_errors_name_the_key():
    base = {"algorithm": "td3", "agent": {"reward": {"imitation": "virl"}, "virl": {}}}
    for key, value, match in (("input", "audio", "agent.virl.input"), ("image_size", 30, "agent.virl.image_size"),
                              ("margin", 0.0, "agent.virl.margin"), ("seq_length", 1, "agent.virl.seq_length"),
                              ("demo_frames", "x", "agent.virl.demo_frames")):
        base["agent"]["virl"] = {key: value}
        with pytest.raises(ConfigError, match=match):
            config_from_dict(base)
    base["agent"]["virl"] = {"seq_reward_weight": 0.0, "frame_reward_weight": 0.0}
    with pytest.raises(ConfigError, match="agent.virl.seq_reward_weight"):
        config_from_dict(base)
    with pytest.raises(ConfigError, match="agent.virl.input"):
        VIRLReward(358, VIRLConfig(input="video"))
    with pytest.raises(ConfigError, match="agent.virl.multitask"):
        VIRLReward(2, VIRLConfig(multitask="no-such-demo"))


def test_state_round_trips_through_safetensors(tmp_path):
    virl = trained(steps=5, multitask="synthetic")
    tensors, meta = virl.state()
    save_file({k: v.contiguous() for k, v in tensors.items()}, tmp_path / "s.safetensors")
    (tmp_path / "s.json").write_text(json.dumps(meta))
    other = VIRLReward(2, VIRLConfig(seq_length=L, **SMALL, multitask="synthetic"), seed=5)
    other.load_state(load_file(tmp_path / "s.safetensors"), json.loads((tmp_path / "s.json").read_text()))
    w = demo_windows()[:10]
    torch.testing.assert_close(other.reward(w[:, -2], w[:, -1], history=w[:, :-1]),
                               virl.reward(w[:, -2], w[:, -1], history=w[:, :-1]), rtol=0, atol=0)
    b = still_batch(16)
    torch.testing.assert_close(torch.tensor(list(other.fit(w[:4], b).values())),
                               torch.tensor(list(virl.fit(w[:4], b).values())))


def test_multitask_pairs_label_clips_and_leave_out_the_demo():
    virl = VIRLReward(2, VIRLConfig(seq_length=L, multitask="synthetic", **SMALL), seed=0)
    others, ids = virl._other_windows(32, demo_windows()[0, 0])
    assert len(virl.others) == 4 and others.shape == (32, L, 2)                           # circle-ccw left out
    x = virl._inputs(others)
    pairs = make_pairs(x[:8], x[8:16], x, ids, 0.05, torch.Generator().manual_seed(0))
    loss, parts = virl_loss(virl.model, pairs, 1.0, (0.7, 0.1, 0.1, 0.1))
    assert torch.isfinite(loss) and set(pairs.label.tolist()) == {0.0, 1.0}


def test_buffer_history_follows_each_env_and_stops_at_resets():
    n_env, steps = 3, 6
    buf = ReplayBuffer(40, transition_specs(1, 1, 0, 1, 1), stride=n_env)
    obs = np.zeros((n_env, 1), np.float32) + np.arange(n_env)[:, None] * 100
    for t in range(steps):
        nxt = obs + 1
        reset = t == 3  # every env's episode ends at step 3: the next obs is a fresh start
        buf.add({"obs": obs, "action": np.zeros((n_env, 1)), "next_obs": nxt, "z": np.zeros((n_env, 0)),
                 "qpos": np.zeros((n_env, 1)), "qvel": np.zeros((n_env, 1)), "terminated": np.full(n_env, reset)})
        obs = nxt + 50 if reset else nxt
    out = buf.sample(np.random.default_rng(0), 200, fields=("obs",), history=4)
    hist, last = out["history"].numpy()[..., 0], out["obs"].numpy()[:, 0]
    assert (hist[:, -1] == last).all()
    for h, o in zip(hist, last):
        env, t = int(o // 100), int(o % 100)  # obs value = 100 * env + its step (+ 50 after the reset)
        start = 54 if t >= 54 else 0
        expect = [100 * env + max(start, t - k) for k in (3, 2, 1, 0)]
        assert h.tolist() == expect, (h, o)


def test_rendering_humanoid_frames_without_gl_fails_with_the_clear_error():
    code = ("import numpy as np\nfrom fbcpr.rewards.virl.frames import render_clip\nfrom humanoid_env.model import default_qpos\n"
            "try:\n    print('RENDERED', render_clip(default_qpos()[None], 64).shape)\n"
            "except RuntimeError as e:\n    print('ERROR', e)\n")
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    env["MUJOCO_GL"] = "glfw"  # a windowing backend without a display
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert "RENDERED (1, 64, 64)" in run.stdout or ("ERROR" in run.stdout and "MUJOCO_GL=glfw" in run.stdout), \
        run.stdout + run.stderr
