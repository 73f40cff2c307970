"""train.device_buffer: batches drawn from a device copy of the replay buffer and the motion frames (run on the CPU
here; the same code runs on a GPU)."""
import shutil

import numpy as np
import pytest
import torch
from test_fbcpr_trainer import state_of
from test_fbcpr_trainer import tiny_cfg as trainer_cfg

from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.train.buffer import FRAME, ReplayBuffer, transition_specs
from fbcpr.train.device_batches import DeviceBatches
from fbcpr.train.resources import check_memory, check_model_memory, memory_bytes
from fbcpr.train.trainer import Trainer
from motions.clip import from_qpos
from motions.library import MotionLibrary

torch.set_num_threads(1)
FIELDS = ("obs", "action", "next_obs", "z", "terminated")
CPU = torch.device("cpu")


def small_buffer(capacity=50):
    return ReplayBuffer(capacity, transition_specs(3, 2, 4, 5, 4))


def transitions(k, start):
    """k transitions whose every field holds its own number (start, start+1, ...), so rows can be matched."""
    ids = np.arange(start, start + k, dtype=np.float32)
    shapes = {"obs": 3, "action": 2, "next_obs": 3, "z": 4, "qpos": 5, "qvel": 4}
    out = {name: np.repeat(ids[:, None], n, 1) + (100_000 * i) for i, (name, n) in enumerate(shapes.items())}
    out["terminated"] = (ids % 2).astype(np.float32)
    return out


class Library:
    """The parts of a MotionLibrary that a sampler reads: frames numbered by clip and frame."""

    def __init__(self, lengths, priorities=None):
        self.lengths = np.asarray(lengths)
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)[:-1]])
        self.frames = np.concatenate([np.stack([np.full(3, 1000 * m + f) for f in range(n)])
                                      for m, n in enumerate(lengths)]).astype(np.float32)
        self.priorities = np.ones(len(lengths)) if priorities is None else np.asarray(priorities, float)


def test_the_copy_follows_the_buffer_through_wraparound_and_dropped_rows():
    buf = small_buffer()
    lib = Library([10])
    batches = DeviceBatches(buf, lib, FIELDS, CPU, seed=0)
    for start in range(0, 120, 7):                 # past the capacity: the ring overwrites its oldest rows
        t = transitions(7, start)
        if start == 14:
            t["obs"][3] = np.nan                       # dropped by the buffer, so not copied either
        batches.added(buf.add(t))
    assert len(buf) == 50 and buf.dropped == 1
    for f in FIELDS:
        np.testing.assert_array_equal(batches.rows[f].numpy(), buf.data[f])


def test_batches_are_whole_transitions_drawn_uniformly_from_the_filled_rows():
    buf = small_buffer(capacity=1000)
    lib = Library([10])
    batches = DeviceBatches(buf, lib, FIELDS, CPU, seed=0)
    batches.added(buf.add(transitions(40, 0)))     # 40 of 1000 rows filled
    batch, _ = batches.sample(8000, 2, 4)
    ids = batch["obs"][:, 0]
    assert set(batch) == set(FIELDS) and batch["obs"].shape == (8000, 3)
    torch.testing.assert_close(batch["action"][:, 0], ids + 100_000)          # every field from the same row
    torch.testing.assert_close(batch["z"][:, 0], ids + 300_000)
    torch.testing.assert_close(batch["terminated"], ids % 2)
    counts = np.bincount(ids.long().numpy(), minlength=40)
    assert len(counts) == 40 and counts.min() > 130 and counts.max() < 270    # 200 each in expectation


def test_windows_are_consecutive_frames_of_one_clip_long_enough_and_follow_priorities():
    lib = Library([3, 12, 20, 9], priorities=[1.0, 1.0, 3.0, 0.0])
    buf = small_buffer()
    batches = DeviceBatches(buf, lib, FIELDS, CPU, seed=1)
    batches.added(buf.add(transitions(5, 0)))
    _, windows = batches.sample(4, 6000, 5)
    assert windows.shape == (6000, 5, 3)
    clip, frame = windows[..., 0] // 1000, windows[..., 0] % 1000
    assert bool((clip == clip[:, :1]).all())                                   # one clip per window
    torch.testing.assert_close(frame - frame[:, :1], torch.arange(5.0).expand(6000, 5))
    assert bool((frame[:, -1] < torch.as_tensor(lib.lengths)[clip[:, 0].long()]).all())  # inside its clip
    share = np.bincount(clip[:, 0].long().numpy(), minlength=4) / 6000
    # clip 0 is shorter than a window and clip 3 has priority 0: clip 2 has 3/4 of the mass, clip 1 the rest
    assert share[0] == 0 and share[3] == 0 and abs(share[2] - 0.75) < 0.03
    lib.priorities = np.array([0.0, 1.0, 0.0, 0.0])                           # replaced, as a priority refresh does
    _, windows = batches.sample(4, 500, 5)
    assert bool((windows[..., 0] // 1000 == 1).all())
    lib.priorities = np.array([1.0, 1.0, 3.0, 0.0])
    batch, windows = batches.sample(4, 300, 5, clips=True)                     # each window marked with its clip
    torch.testing.assert_close(batch["window_clip"].float(), windows[:, 0, 0] // 1000)
    assert "window_clip" not in batches.sample(4, 3, 5)[0]


def test_the_frames_are_the_motion_librarys():
    rng = np.random.default_rng(0)
    clips = []
    for i, n in enumerate((12, 20)):
        qpos = np.zeros((n, 76))
        qpos[:, 2], qpos[:, 3] = 0.9, 1.0                               # standing height, upright root
        qpos[:, 7:] = np.cumsum(rng.normal(0, 0.01, (n, 69)), 0)       # joints drifting slowly
        clips.append(from_qpos(qpos, f"c{i}"))
    lib = MotionLibrary(clips)
    np.testing.assert_array_equal(lib.frames[lib.offsets[1]:], clips[1].obs)
    batches = DeviceBatches(small_buffer(), lib, FIELDS, CPU, seed=0)
    np.testing.assert_array_equal(batches.frames.numpy(), lib.frames)


def test_an_empty_buffer_and_unknown_fields_are_errors():
    with pytest.raises(ValueError, match="no field 'history'"):
        DeviceBatches(small_buffer(), Library([10]), ("obs", "history"), CPU, seed=0)
    with pytest.raises(RuntimeError, match="empty"):
        DeviceBatches(small_buffer(), Library([10]), FIELDS, CPU, seed=0).sample(4, 1, 2)


def tiny_cfg(**train):
    """The trainer tests' toy run (its exact resume is checked there), drawing its batches on the device."""
    return trainer_cfg(**{"device_buffer": True, **train})


def test_a_run_on_device_batches_trains_and_resumes_bit_for_bit(tmp_path):
    a = Trainer(tiny_cfg(), tmp_path / "a", progress=False)
    a.run(max_env_steps=120)
    assert a.learner.updates > 0
    for f in FIELDS:                                # the copy followed every add
        np.testing.assert_array_equal(a.batches.rows[f][: len(a.buffer)].numpy(), a.buffer.data[f][: len(a.buffer)])
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    a.run(max_env_steps=80)
    b = Trainer(tiny_cfg(), tmp_path / "b", resume=True, progress=False)
    b.run(max_env_steps=80)
    wa, wb = state_of(a), state_of(b)
    assert wa.keys() == wb.keys()
    assert not [k for k in wa if not torch.equal(wa[k], wb[k])]
    # the host draw gives other batches from the same start, so the comparison above is not vacuous
    c = Trainer(tiny_cfg(device_buffer=False), tmp_path / "c", progress=False)
    c.run(max_env_steps=200)
    assert any(not torch.equal(wa[k], v) for k, v in state_of(c).items())


def test_sequence_rewards_and_a_copy_that_cannot_fit_are_config_errors(tmp_path):
    cfg = config_from_dict({"algorithm": "td3", "agent": {"batch_size": 32, "reward": {"imitation": "virl"}},
                            "model": {"hidden_dim": 16, "hidden_layers": 1},
                            "env": {"name": "toy", "max_episode_steps": 30},
                            "train": {"num_envs": 4, "buffer_capacity": 1000, "device_buffer": True,
                                      "priority_every": 0, "reward_buffer_size": 0}})
    with pytest.raises(ConfigError, match="^train.device_buffer: .*sequence reward"):
        Trainer(cfg, tmp_path / "virl", progress=False)
    # a capacity whose buffer fits this machine's memory but not a second copy of its training fields
    cfg = tiny_cfg(buffer_memmap_mb=10**9, save_buffer=False)     # no checkpoint holding the buffer: no disk check
    cfg.model.obs_dim, cfg.model.action_dim = 2, 2
    specs = transition_specs(2, 2, cfg.model.z_dim, 2, 2)
    row, copy_row = ReplayBuffer.bytes_needed(1, specs), DeviceBatches.bytes_needed(1, specs, FIELDS)
    cfg.train.buffer_capacity = int(memory_bytes(CPU) / (row + copy_row / 2))
    with pytest.raises(ConfigError, match="^train.device_buffer: its copy of the replay buffer needs"):
        check_memory(cfg, specs, check_model_memory(cfg, CPU), tmp_path, CPU)
    cfg.train.device_buffer = False
    model = check_model_memory(cfg, CPU)
    assert check_memory(cfg, specs, model, tmp_path, CPU) is False                  # the buffer alone fits, in memory
    # a video reward's frames are part of every transition: 64x64 of them no longer fit at that capacity
    with pytest.raises(ConfigError, match="^train.buffer_capacity: the replay buffer needs"):
        check_memory(cfg, {**specs, FRAME: (64, 64)}, model, tmp_path, CPU)
