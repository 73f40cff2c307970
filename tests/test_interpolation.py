"""Weight interpolation of two checkpoints (`fbcpr.inference.interpolation`, `fbcpr export --interpolate`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import humanoid_states, tiny_humanoid_checkpoint
from fbcpr import BFM
from fbcpr.core.checkpoint import CheckpointError
from fbcpr.cli.app import app
from fbcpr.core.errors import InputError
from fbcpr.inference.interpolation import interpolate, with_reward_states

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("interp")
    return tiny_humanoid_checkpoint(root, "base", seed=0), tiny_humanoid_checkpoint(root, "tuned", seed=1)


def _weights(bfm: BFM) -> dict[str, torch.Tensor]:
    return {k: v.double() for k, v in bfm.model.state_dict().items()}


@pytest.mark.parametrize("alpha", [0.0, 0.3, 1.0])
def test_every_tensor_is_the_weighted_mean_and_the_buffer_is_the_tuned_models(pair, alpha):
    base, tuned = BFM.load(pair[0]), BFM.load(pair[1])
    mixed = interpolate(base, tuned, alpha)
    wa, wb, wm = _weights(base), _weights(tuned), _weights(mixed)
    assert wm.keys() == wa.keys()
    for key in wa:
        torch.testing.assert_close(wm[key], (1 - alpha) * wa[key] + alpha * wb[key], rtol=1e-6, atol=1e-6)
    assert "obs_normalizer.mean" in wm and not torch.equal(wa["obs_normalizer.mean"], wb["obs_normalizer.mean"])
    np.testing.assert_array_equal(mixed.reward_buffer["qpos"], tuned.reward_buffer["qpos"])
    assert mixed.action_mapping == tuned.action_mapping
    # the inputs are left as they were
    for key, value in _weights(BFM.load(pair[1])).items():
        torch.testing.assert_close(wb[key], value)


def test_midpoint_acts_and_round_trips(pair, tmp_path):
    mixed = interpolate(BFM.load(pair[0]), BFM.load(pair[1]), 0.5)
    obs = humanoid_states(4, seed=3)["next_obs"].astype(np.float32)
    z = mixed.reward_z("move-ego-0-0")
    reloaded = BFM.load(mixed.save(tmp_path / "mixed"))
    np.testing.assert_allclose(reloaded.act(obs, z), mixed.act(obs, z), atol=1e-6)
    assert np.all(np.abs(mixed.act(obs, z)) <= 1.0)


@pytest.mark.parametrize("alpha", [-0.1, 1.5, float("nan"), "half"])
def test_alpha_outside_the_unit_interval_is_named(pair, alpha):
    with pytest.raises(InputError, match="alpha"):
        interpolate(BFM.load(pair[0]), BFM.load(pair[1]), alpha)


@pytest.mark.parametrize("other, match", [({"preset": "small"}, "model config"),
                                          ({"mapping": "mid"}, "action mapping")])
def test_models_that_do_not_share_an_architecture_are_refused(pair, tmp_path, other, match):
    odd = tiny_humanoid_checkpoint(tmp_path, "odd", seed=2, **other)
    with pytest.raises(CheckpointError, match=match):
        interpolate(BFM.load(pair[0]), BFM.load(odd), 0.5)


def test_export_interpolate_writes_the_mixed_weights(pair, tmp_path):
    out = tmp_path / "export"
    res = CliRunner().invoke(app, ["export", str(pair[1]), str(out), "--interpolate", str(pair[0]),
                                   "--alpha", "0.25", "--reward-samples", "16"])
    assert res.exit_code == 0, res.output
    expected = _weights(interpolate(BFM.load(pair[0]), BFM.load(pair[1]), 0.25))
    got = _weights(BFM.load(out))
    for key in expected:
        torch.testing.assert_close(got[key], expected[key], rtol=1e-6, atol=1e-6)
    assert len(BFM.load(out).reward_buffer["qpos"]) == 16
    held = len(BFM.load(pair[1]).reward_buffer["qpos"])
    assert f"a seeded 16 of the {held:,} kept (--reward-samples)" in " ".join(res.output.split())
    assert "fbcpr/configs/own-states.yaml" in res.output   # the mix's states are borrowed: how to make its own


def test_export_interpolate_with_a_bad_alpha_is_a_clear_error(pair, tmp_path):
    res = CliRunner().invoke(app, ["export", str(pair[1]), str(tmp_path / "x"), "--interpolate", str(pair[0]),
                                   "--alpha", "2"])
    assert res.exit_code != 0
    assert "alpha" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "x").exists()


def test_export_alpha_without_interpolate_is_refused(pair, tmp_path):
    res = CliRunner().invoke(app, ["export", str(pair[1]), str(tmp_path / "y"), "--alpha", "0.3"])
    assert res.exit_code != 0
    assert "--interpolate" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "y").exists()


def test_export_reward_states_from_keeps_the_weights_and_takes_the_donors_states(pair, tmp_path):
    out = tmp_path / "donated"
    res = CliRunner().invoke(app, ["export", str(pair[1]), str(out), "--reward-states-from", str(pair[0]),
                                   "--reward-samples", "16", "--full"])
    assert res.exit_code == 0, res.output
    got, tuned, donor = BFM.load(out), BFM.load(pair[1]), BFM.load(pair[0])
    for key, value in _weights(tuned).items():
        torch.testing.assert_close(_weights(got)[key], value, rtol=0, atol=0)
    donor_rows = {row.tobytes() for row in donor.reward_buffer["qpos"].astype(np.float32)}
    tuned_rows = {row.tobytes() for row in tuned.reward_buffer["qpos"].astype(np.float32)}
    got_rows = [row.tobytes() for row in got.reward_buffer["qpos"].astype(np.float32)]
    assert len(got_rows) == 16 and all(r in donor_rows and r not in tuned_rows for r in got_rows)
    assert "own-states" not in res.output            # states chosen: no hint


def test_reward_states_from_a_model_of_another_action_mapping_are_refused(pair, tmp_path):
    odd = BFM.load(tiny_humanoid_checkpoint(tmp_path, "odd", seed=2, mapping="mid"))
    with pytest.raises(CheckpointError, match="action mapping"):
        with_reward_states(BFM.load(pair[1]), [odd])
    res = CliRunner().invoke(app, ["export", str(pair[1]), str(tmp_path / "z"), "--reward-states-from",
                                   str(tmp_path / "odd")])
    assert res.exit_code != 0 and "action mapping" in res.output and "Traceback" not in res.output
    assert not (tmp_path / "z").exists()


def test_reward_states_of_several_models_are_pooled(pair):
    base, tuned = BFM.load(pair[0]), BFM.load(pair[1])
    pooled = with_reward_states(tuned, [base, tuned]).reward_buffer
    for key in ("next_obs", "qpos", "qvel"):
        expected = np.concatenate([base.reward_buffer[key], tuned.reward_buffer[key]]).astype(np.float32)
        np.testing.assert_array_equal(pooled[key], expected)
    with pytest.raises(InputError, match="at least one"):
        with_reward_states(tuned, [])
