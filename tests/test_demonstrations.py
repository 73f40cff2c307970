"""Demonstrations with actions: saved and read back with their checks, and added to a run's replay buffer as the
transitions the env makes of them (`train.demonstrations`)."""
import numpy as np
import pytest
import torch

from fbcpr.config import ConfigError, config_from_dict
from fbcpr.trainer import Trainer
from humanoid_env.model import NU, NV, default_qpos
from humanoid_env.planner import PlannerConfig, TrackingPlanner
from motions.clip import Clip
from motions.library import MotionLibrary
from motions.demonstrations import (
    ACTIONS_SUFFIX,
    Demonstration,
    DemonstrationError,
    actions_path,
    load_demonstrations,
    save_demonstration,
)

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def planned():
    """A short planned motion: 6 steps of holding the stand after a shove."""
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.4
    planner = TrackingPlanner(default_qpos()[None], PlannerConfig(samples=3, horizon=4, knot_every=2))
    m = planner.run(q0, v0, steps=6)
    clip = Clip(qpos=m.qpos, qvel=m.qvel, obs=m.obs, name="shoved", source="planner test", license="CC0")
    return Demonstration(clip, m.actions, planner.amap.mapping)


def test_a_saved_demonstration_reads_back(tmp_path, planned):
    save_demonstration(planned, tmp_path / "shoved.npz")
    assert actions_path(tmp_path / "shoved.npz").name == "shoved" + ACTIONS_SUFFIX
    (back,) = load_demonstrations(tmp_path)
    np.testing.assert_array_equal(back.actions, planned.actions)
    np.testing.assert_allclose(back.clip.qpos, planned.clip.qpos)
    assert back.action_mapping == "rest" and back.clip.name == "shoved"


def test_a_demonstration_folder_is_also_a_clip_folder(tmp_path, planned):
    save_demonstration(planned, tmp_path / "shoved.npz")
    library = MotionLibrary.load(tmp_path)
    assert [c.name for c in library.clips] == ["shoved"]


def test_bad_demonstrations_are_named(tmp_path, planned):
    with pytest.raises(DemonstrationError, match="no such"):
        load_demonstrations(tmp_path / "missing")
    with pytest.raises(DemonstrationError, match="holds no"):
        load_demonstrations(tmp_path)
    bad = Demonstration(planned.clip, planned.actions[:-1], "rest")
    with pytest.raises(DemonstrationError, match="shape"):
        save_demonstration(bad, tmp_path / "short.npz")
    save_demonstration(planned, tmp_path / "a.npz")
    actions_path(tmp_path / "a.npz").unlink()
    with pytest.raises(DemonstrationError, match="no actions beside"):
        load_demonstrations(tmp_path)
    for name, actions in (("nan", np.where(np.arange(NU) == 3, np.nan, planned.actions)),
                          ("big", planned.actions * 3 + 2)):
        (tmp_path / "a.npz").unlink()
        save_demonstration(planned, tmp_path / "a.npz")
        np.savez(actions_path(tmp_path / "a.npz"), actions=actions.astype(np.float32), action_mapping=np.array("rest"))
        with pytest.raises(DemonstrationError, match="NaN" if name == "nan" else r"\[-1, 1\]"):
            load_demonstrations(tmp_path)
    actions_path(tmp_path / "a.npz").write_bytes(b"not a zip")
    with pytest.raises(DemonstrationError, match=str(actions_path(tmp_path / "a.npz").name)):
        load_demonstrations(tmp_path)


def humanoid_cfg(clips, demos, **train):
    return config_from_dict({
        "algorithm": "td3",
        "model": {"hidden_dim": 16, "hidden_layers": 1},
        "agent": {"batch_size": 8, "reward": {"task": "move-ego-0-0"}},
        "env": {"name": "humanoid", "motions": str(clips), "max_episode_steps": 20},
        "train": {"total_env_steps": 1000, "num_envs": 2, "warmup_steps": 4, "rollout_steps": 4,
                  "updates_per_rollout": 1, "buffer_capacity": 200, "priority_every": 0, "eval_every": 0,
                  "checkpoint_every": 0, "log_every": 40, "reward_buffer_size": 0, "torch_threads": 1,
                  "demonstrations": str(demos), **train},
    })


def test_a_run_starts_with_the_demonstrations_in_its_buffer(tmp_path, two_clips, planned):
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    tr = Trainer(humanoid_cfg(two_clips, tmp_path / "demos", demonstration_copies=3), tmp_path / "run", progress=False)
    try:
        assert len(tr.buffer) == 18
        data = tr.buffer.data
        for copy in range(3):
            rows = slice(6 * copy, 6 * copy + 6)
            np.testing.assert_allclose(data["action"][rows], planned.actions)
            np.testing.assert_allclose(data["obs"][rows], planned.clip.obs[:-1])
            np.testing.assert_allclose(data["next_obs"][rows], planned.clip.obs[1:])
            np.testing.assert_allclose(data["qpos"][rows], planned.clip.qpos[1:], rtol=1e-6, atol=1e-6)
        assert not data["terminated"][:18].any()
        tr.run(max_env_steps=8)  # the env's own transitions follow them
        assert len(tr.buffer) == 18 + 8
    finally:
        tr.close()


def test_demonstrations_that_do_not_fit_the_run_are_config_errors(tmp_path, two_clips, planned):
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    with pytest.raises(ConfigError, match=r"over half of train.buffer_capacity over 20 demonstration_copies "
                                          r"\(5 transitions\) by shoved.npz"):
        Trainer(humanoid_cfg(two_clips, tmp_path / "demos", demonstration_copies=20), tmp_path / "a", progress=False)
    mid = humanoid_cfg(two_clips, tmp_path / "demos")
    mid.env.action_mapping = "mid"
    with pytest.raises(ConfigError, match="'rest' action mapping"):
        Trainer(mid, tmp_path / "b", progress=False)
    with pytest.raises(ConfigError, match="train.demonstrations: .*no such"):
        Trainer(humanoid_cfg(two_clips, tmp_path / "nowhere"), tmp_path / "c", progress=False)
