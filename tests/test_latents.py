"""fbcpr.nn.latents: the shared z maths against the App. C.5.3 formulas written out as loops, and its two users agreeing."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.core.config import config_from_dict
from fbcpr.eval.tracking import tracking_latents
from fbcpr.nn.latents import reward_weights, tracking_sums
from fbcpr.methods.fb_cpr.model import FBCPRModel

torch.set_num_threads(1)


@pytest.mark.parametrize("T, L", [(1, 3), (2, 3), (7, 1), (7, 3), (7, 10)])
def test_tracking_sums_are_next_l_states_with_the_last_held(T, L):
    b = torch.randn(T, 5, dtype=torch.float64, generator=torch.Generator().manual_seed(T * 10 + L))
    out = tracking_sums(b, L)
    assert out.shape == (T, 5)
    for t in range(T - 1):
        torch.testing.assert_close(out[t], b[t + 1: min(t + 1 + L, T)].sum(0))
    torch.testing.assert_close(out[T - 1], b[T - 1])  # nothing after the last state: it is its own target


def test_reward_weights_are_the_weighted_and_plain_regressions():
    r = torch.tensor([0.0, 0.2, 1.0, 0.5, -0.3], dtype=torch.float64)
    w = reward_weights(r, 10.0)
    expected = torch.exp(10.0 * r) * r
    torch.testing.assert_close(w / w.sum(), expected / expected.sum())  # same direction as exp(τ r) r
    assert w[0] == 0 and w[4] < 0 and w.argmax() == 2
    torch.testing.assert_close(reward_weights(r, None), r / 5)
    big = reward_weights(torch.tensor([100.0, 99.0]), 10.0)  # exp(1000) would overflow without the shift
    assert torch.isfinite(big).all() and big[0] > big[1] > 0


def test_training_tracking_and_prompt_track_give_the_same_zs():
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 2},
                            "agent": {"seq_length": 3, "batch_size": 9}})
    model = FBCPRModel(cfg.model)
    obs = np.random.default_rng(0).normal(size=(9, 6)).astype(np.float32)
    z_train = tracking_latents(model, obs, 3).numpy()
    z_prompt = BFM(model, cfg).prompt.track(obs)
    assert z_train.shape == (9, 8) and z_prompt.shape == (8, 8)
    np.testing.assert_allclose(z_train[:-1], z_prompt, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(z_train[-1], z_train[-2])  # training rollouts hold the last z one step more
