"""Demonstrations with actions: saved and read back with their checks, and added to a run's replay buffer as the
transitions the env makes of them (`train.demonstrations`)."""
import numpy as np
import pytest
import torch

from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.train.trainer import Trainer
from humanoid_env.model import NU, NV, default_qpos
from humanoid_env.env import HumanoidEnv
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
    """A short motion with the actions that made it: 6 steps of small random actions after a shove."""
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.4
    env = HumanoidEnv()
    obs, info = env.reset(seed=0, options={"qpos": q0, "qvel": v0})
    rng = np.random.default_rng(0)
    qpos, qvel, seen, actions = [info["qpos"]], [info["qvel"]], [obs], rng.uniform(-0.1, 0.1, (6, NU))
    for a in actions:
        obs, _, _, _, info = env.step(a)
        qpos.append(info["qpos"]), qvel.append(info["qvel"]), seen.append(obs)
    clip = Clip(qpos=np.array(qpos), qvel=np.array(qvel), obs=np.array(seen, dtype=np.float32), name="shoved",
                source="random actions", license="CC0")
    return Demonstration(clip, actions.astype(np.float32), env.action_map.mapping)


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


def test_demonstrations_held_apart_fill_a_share_of_every_batch(tmp_path, two_clips, planned):
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    cfg = humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.25)
    tr = Trainer(cfg, tmp_path / "run", progress=False)
    try:
        assert len(tr.buffer) == 0  # not in the FIFO, where the env's transitions would overwrite them
        tr.run(max_env_steps=8)
        batch, _ = tr.learner.sample_batch()
        assert batch["demo"].tolist() == [True, True] + [False] * 6
        for row in range(2):  # each marked row is one of the demonstration's transitions, fields aligned
            (step,) = np.flatnonzero(np.isclose(planned.clip.obs[:-1], batch["obs"][row].numpy(), rtol=1e-6).all(axis=1))
            np.testing.assert_allclose(batch["action"][row], planned.actions[step], rtol=1e-6)
            np.testing.assert_allclose(batch["next_obs"][row], planned.clip.obs[step + 1], rtol=1e-6)
            np.testing.assert_allclose(batch["qvel"][row], planned.clip.qvel[step + 1], rtol=1e-5, atol=1e-5)
            # the demonstrator's next action, where the demonstration goes on
            assert batch["demo_next"][row] == (step < len(planned.actions) - 1)
            if step < len(planned.actions) - 1:
                np.testing.assert_allclose(batch["demo_next_action"][row], planned.actions[step + 1], rtol=1e-6)
        assert not batch["demo_next"][2:].any() and not batch["demo_next_action"][2:].any()
        assert batch["terminated"].dtype == tr.buffer.sample(tr.rng, 1)["terminated"].dtype
        assert not batch["terminated"][:2].any()
        online = batch["obs"][2:].numpy()
        assert not np.isin(online, planned.clip.obs).all(axis=1).any()
    finally:
        tr.close()


def test_behaviour_cloning_pulls_the_policy_to_the_demonstrated_actions(tmp_path, two_clips, planned):
    """TD3+BC: on the marked rows the actor moves toward the demonstrations' actions; without the term it does not."""
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    errors = {}
    for weight in (0.0, 5.0):
        cfg = humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.5)
        cfg.agent.bc_weight, cfg.agent.lr_actor = weight, 1e-3
        tr = Trainer(cfg, tmp_path / f"run{weight}", progress=False)
        try:
            tr.run(max_env_steps=8)
            obs = torch.as_tensor(planned.clip.obs[:-1])
            model = tr.agent.model
            error = lambda: (model.actor_mean(model.normalize(obs)) - torch.as_tensor(planned.actions)).square().mean()  # noqa: E731
            before = error().item()
            for _ in range(150):
                metrics = tr.agent.update(*tr.learner.sample_batch())
            errors[weight] = error().item() / before
            assert ("bc_loss" in metrics) == (weight > 0)
        finally:
            tr.close()
    assert errors[5.0] < 0.5 and errors[5.0] < 0.5 * errors[0.0], errors


def test_demonstration_rows_can_bootstrap_on_the_demonstrators_next_action(tmp_path, two_clips, planned):
    """With agent.bootstrap_demo_actions the critic's target reads the batch's demo_next_action on marked rows (two
    copies of one agent, batches that differ only there, differ in their critic loss); without it, it does not."""
    import copy

    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    for on in (False, True):
        cfg = humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.5)
        cfg.agent.bootstrap_demo_actions = on
        tr = Trainer(cfg, tmp_path / f"run{on}", progress=False)
        try:
            tr.run(max_env_steps=8)
            batch, windows = tr.learner.sample_batch()
            assert batch["demo_next"].any()
            other = dict(batch, demo_next_action=1.0 - batch["demo_next_action"].abs())
            a, b = copy.deepcopy(tr.agent), copy.deepcopy(tr.agent)
            losses = a.update(batch, windows)["critic_loss"], b.update(other, windows)["critic_loss"]
            assert (losses[0] != losses[1]) == on, losses
        finally:
            tr.close()


def test_demonstration_shares_that_cannot_work_are_config_errors(tmp_path, two_clips):
    base = humanoid_cfg(two_clips, tmp_path / "demos")
    data = {"algorithm": "td3", "agent": {"reward": {"task": "move-ego-0-0"}}, "env": {"name": "humanoid"}}
    with pytest.raises(ConfigError, match="train.demonstration_share: draws from train.demonstrations"):
        config_from_dict({**data, "train": {"demonstration_share": 0.2}})
    with pytest.raises(ConfigError, match="train.demonstration_copies: copies go into the replay buffer"):
        config_from_dict({**data, "train": {"demonstrations": "d", "demonstration_share": 0.2, "demonstration_copies": 2}})
    with pytest.raises(ConfigError, match="agent.bc_weight: .* needs train.demonstration_share"):
        config_from_dict({**data, "agent": {**data["agent"], "bc_weight": 1.0}, "train": {"demonstrations": "d"}})
    with pytest.raises(ConfigError, match="agent.bootstrap_demo_actions: .* needs train.demonstration_share"):
        config_from_dict({**data, "agent": {**data["agent"], "bootstrap_demo_actions": True}})
    with pytest.raises(ConfigError, match=r"train.demonstration_share: must be in \[0.0, 0.5\]"):
        config_from_dict({**data, "train": {"demonstrations": "d", "demonstration_share": 0.9}})
    assert base.train.demonstration_share == 0.0


def test_behaviour_cloning_pulls_toward_an_experts_labels_where_a_rollout_carries_them(tmp_path, two_clips, planned):
    """DAgger: a labelled rollout's transitions are its own actions, and BC pulls the policy to the labels."""
    labels = np.clip(0.5 - planned.actions, -1.0, 1.0).astype(np.float32)   # far from the actions
    save_demonstration(Demonstration(planned.clip, planned.actions, "rest", labels), tmp_path / "demos" / "l.npz")
    cfg = humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.5)
    cfg.agent.bc_weight, cfg.agent.lr_actor = 5.0, 1e-3
    tr = Trainer(cfg, tmp_path / "run", progress=False)
    try:
        np.testing.assert_allclose(tr.learner.demos["demo_target"].numpy(), labels)
        np.testing.assert_allclose(tr.learner.demos["action"].numpy(), planned.actions)
        tr.run(max_env_steps=8)
        model = tr.agent.model
        obs = model.normalize(torch.as_tensor(planned.clip.obs[:-1]))
        to = lambda target: (model.actor_mean(obs) - torch.as_tensor(target)).square().mean().item()  # noqa: E731
        before = to(labels)
        for _ in range(150):
            tr.agent.update(*tr.learner.sample_batch())
        assert to(labels) < 0.5 * before and to(labels) < to(planned.actions)
    finally:
        tr.close()
    cfg = humanoid_cfg(two_clips, tmp_path / "demos", demonstration_share=0.5)   # labels without BC: an error
    with pytest.raises(ConfigError, match="shoved carries an expert's labels, which only behaviour cloning reads"):
        Trainer(cfg, tmp_path / "run2", progress=False)
