"""The progress imitation reward: later frames pay more, far states nearly nothing, and its bounds and errors."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from conftest import humanoid_states
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.core.registry import imitation_reward
from fbcpr.rewards.progress import MAX_FRAMES, ProgressConfig, ProgressReward
from fbcpr.core.protocols import ImitationReward
from motions import synthetic
from motions.library import MotionLibrary

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def raise_arms():
    """The first quarter of the synthetic arm raise: the left arm goes from down to horizontal, a motion with a
    direction."""
    clip = synthetic.arm_raise(6.0)
    k = clip.n_frames // 4
    return type(clip)(clip.qpos[:k], clip.qvel[:k], clip.obs[:k], "raise", clip.source, clip.license, clip.fps)


def test_later_frames_pay_more_and_the_last_pays_one(raise_arms):
    reward = ProgressReward(358, ProgressConfig(), library=MotionLibrary([raise_arms]))
    assert isinstance(reward, ImitationReward)
    frames = torch.as_tensor(raise_arms.obs)
    r = reward.reward(frames, frames).numpy()
    progress = np.arange(1, len(r) + 1) / len(r)
    assert (r >= progress - 1e-6).all() and r[-1] == pytest.approx(1.0)
    quarters = [r[i * len(r) // 4:(i + 1) * len(r) // 4].mean() for i in range(4)]
    assert quarters == sorted(quarters) and quarters[0] < 0.6 < 0.9 < quarters[-1]
    far = torch.as_tensor(humanoid_states(8, 0, drop=(-0.9, -0.7))["next_obs"], dtype=torch.float32)
    assert reward.reward(far, far).max() < 0.5 * r[-1]
    assert reward.fit(frames[None], {}) == {} and reward.state() == ({}, {})


def test_a_wider_scale_pays_more_for_the_same_distance(raise_arms):
    lib = MotionLibrary([raise_arms])
    far = torch.as_tensor(humanoid_states(4, 1)["next_obs"], dtype=torch.float32)
    narrow, wide = (ProgressReward(358, ProgressConfig(scale=s), library=lib).reward(far, far) for s in (1.0, 6.0))
    assert (wide > narrow).all()


def test_td3_builds_it_from_its_config_section(raise_arms):
    cfg = config_from_dict({"algorithm": "td3", "agent": {"reward": {"imitation": "progress"},
                                                          "progress": {"scale": 2.0}}})
    reward = imitation_reward("progress", 358, cfg.agent, torch.device("cpu"), 0, MotionLibrary([raise_arms]))
    assert isinstance(reward, ProgressReward) and reward.cfg.scale == 2.0


def test_errors_name_the_setting():
    with pytest.raises(ConfigError, match="agent.reward.imitation: progress needs the env's demonstration clips"):
        ProgressReward(358, ProgressConfig())
    huge = SimpleNamespace(clips=[SimpleNamespace(n_frames=MAX_FRAMES + 1)])
    with pytest.raises(ConfigError, match="at most 20,000"):
        ProgressReward(358, ProgressConfig(), library=huge)
    with pytest.raises(ConfigError, match="agent.progress.scale"):
        config_from_dict({"algorithm": "td3", "agent": {"reward": {"imitation": "progress"}, "progress": {"scale": 0}}})
