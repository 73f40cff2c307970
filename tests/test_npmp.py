"""NPMP: the AR(1) KL, encoder windows, LFPC Jacobians, the dataset format, distillation and its checkpoints,
on a tiny random BFM and a two-clip synthetic library."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch

from fbcpr.inference.bfm import BFM
from fbcpr.core.checkpoint import CheckpointError, latest_checkpoint, load_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError, InputError
from fbcpr.inference.agents import load_tracker, make_agent
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.apps.npmp.agent import NPMPAgent
from fbcpr.apps.npmp.config import npmp_config
from fbcpr.apps.npmp.data import DataError, ExpertData, collect, expert_jacobian
from fbcpr.apps.npmp.distill import Distiller, distill
from fbcpr.apps.npmp.model import NPMPModel, future_indices, kl_to_prior
from fbcpr.core.errors import PromptError
from humanoid_env.model import load_model
from motions.clip import from_qpos
from motions.library import MotionLibrary

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def bfm() -> BFM:
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    model = FBCPRModel(cfg.model)
    return BFM(model, cfg)


@pytest.fixture(scope="module")
def library() -> MotionLibrary:
    q0 = load_model().qpos0
    swing = np.tile(q0, (6, 1))
    swing[:, 7 + 45] = np.linspace(0.0, 0.8, 6)
    return MotionLibrary([from_qpos(swing, name="arm_swing"), from_qpos(np.tile(q0, (3, 1)), name="stand")])


@pytest.fixture(scope="module")
def bc_data(bfm, library) -> ExpertData:
    return collect(bfm, library, "bc", rollouts=2, noise=0.1, max_steps=4, seed=0)


@pytest.fixture(scope="module")
def lfpc_data(bfm, library) -> ExpertData:
    return collect(bfm, library, "lfpc", max_steps=4, perturb_scale=0.05)


def tiny(**kw) -> NPMPModel:
    torch.manual_seed(0)
    return NPMPModel(npmp_config(kw, preset="tiny"), 358, 69)


def test_kl_matches_the_gaussian_formula_and_vanishes_at_the_prior():
    alpha, z_prev = 0.95, torch.tensor([[0.5, -1.0]])
    sigma = math.sqrt(1 - alpha**2)
    mean, std = torch.tensor([[0.3, -0.2]]), torch.tensor([[0.1, 0.5]])
    by_hand = sum(math.log(sigma / s) + (s**2 + (m - alpha * zp) ** 2) / (2 * sigma**2) - 0.5
                  for m, s, zp in zip(mean[0].tolist(), std[0].tolist(), z_prev[0].tolist()))
    assert float(kl_to_prior(mean, std.log(), z_prev, alpha)) == pytest.approx(by_hand, rel=1e-5)
    at_prior = kl_to_prior(alpha * z_prev, torch.full_like(z_prev, math.log(sigma)), z_prev, alpha)
    assert float(at_prior) == pytest.approx(0.0, abs=1e-6)
    # alpha = 0: the i.i.d. N(0, I) prior, whatever z_{t-1}
    assert float(kl_to_prior(torch.zeros(1, 2), torch.zeros(1, 2), z_prev, 0.0)) == pytest.approx(0.0, abs=1e-7)


def test_shapes_and_the_encoder_window_rule_for_short_clips():
    m = tiny()
    assert future_indices(3, 2).tolist() == [[0, 1, 2], [1, 2, 2], [2, 2, 2]]  # past the end: the last frame
    frames = torch.randn(2, 358)  # a clip shorter than K + 1 frames
    z = m.encode(frames)
    assert z.shape == (1, 4) and torch.isfinite(z).all()
    mean, log_std = m.posterior(torch.zeros(5, 4), torch.randn(5, 3, 358))
    assert mean.shape == log_std.shape == (5, 4)
    assert m.decode(torch.randn(5, 358), mean).shape == (5, 69)
    with pytest.raises(ValueError, match="frames"):
        m.encode(torch.randn(1, 358))


def test_lfpc_jacobian_matches_finite_differences(bfm):
    rng = np.random.default_rng(0)
    obs = torch.as_tensor(rng.normal(size=(3, 358)), dtype=torch.float32)
    z = bfm.model.project_z(torch.randn(3, bfm.z_dim))
    jac = expert_jacobian(bfm, obs, z).double()
    dirs = torch.as_tensor(rng.normal(size=(3, 358)), dtype=torch.float64) * 1e-6
    m = copy.deepcopy(bfm.model).double()  # central differences in float64, on a copy of the expert
    with torch.no_grad():
        fd = (m.actor_mean(m.normalize(obs.double() + dirs), z.double())
              - m.actor_mean(m.normalize(obs.double() - dirs), z.double())) / 2
    np.testing.assert_allclose(torch.einsum("nad,nd->na", jac, dirs), fd, rtol=1e-3, atol=1e-10)


def test_collect_logs_episodes_and_round_trips(bc_data, lfpc_data, library, tmp_path):
    # BC: 2 rollouts x 2 clips, each at most 4 steps (5 states); the first rollout of a clip starts at frame 0
    assert len(bc_data.episode_clip) == 4 and bc_data.jacobian is None
    assert bc_data.episode_frame[0] == 0 and int(bc_data.lengths.max()) <= 5
    assert lfpc_data.jacobian.shape == (len(lfpc_data.obs), 69, 358) and lfpc_data.jacobian.dtype == torch.float16
    assert (lfpc_data.lengths == torch.tensor([5, 3])).all()  # to each clip's end: 6 and 3 frames
    path = lfpc_data.save(tmp_path / "data.safetensors")
    back = ExpertData.load(path)
    assert back.method == "lfpc" and back.clip_names == library.names
    assert torch.equal(back.obs, lfpc_data.obs) and torch.equal(back.jacobian, lfpc_data.jacobian)


def test_bad_dataset_files_are_clear_errors(bc_data, tmp_path):
    with pytest.raises(DataError, match="no such expert-data file"):
        ExpertData.load(tmp_path / "missing.safetensors")
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x80\x04not a safetensors file")
    with pytest.raises(DataError, match="not a readable safetensors"):
        ExpertData.load(junk)
    from safetensors.torch import save_file

    other = tmp_path / "other.safetensors"
    save_file({"obs": torch.zeros(2, 358)}, str(other))
    with pytest.raises(DataError, match="not an NPMP expert dataset"):
        ExpertData.load(other)
    bad = bc_data.obs.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(DataError, match="obs: contains NaN"):
        ExpertData(**{**bc_data.__dict__, "obs": bad})
    with pytest.raises(DataError, match="jacobian"):
        ExpertData(**{**bc_data.__dict__, "method": "lfpc"})


def test_dataset_size_is_bounded_before_any_simulation(bfm, library):
    with pytest.raises(DataError, match="over the .* limit: lower --max-steps"):
        collect(bfm, library, "lfpc", max_steps=4, max_bytes=10_000)
    with pytest.raises(DataError, match="method"):
        collect(bfm, library, "dagger")


@pytest.mark.parametrize("method", ["bc", "lfpc"])
def test_distillation_loss_decreases(method, bc_data, lfpc_data):
    data = bc_data if method == "bc" else lfpc_data
    model = tiny()
    model.obs_normalizer.update(data.obs)
    d = Distiller(model, data)
    frames, targets, mask = d.batch()
    assert frames.shape == (4, 6, 358) and targets.shape == (4, 4, 69) and mask.shape == (4, 4)
    with torch.no_grad():
        before = float(d.losses(*d.batch())["loss"])
    for _ in range(30):
        d.update()
    with torch.no_grad():
        after = np.mean([float(d.losses(*d.batch())["loss"]) for _ in range(5)])
    assert after < 0.7 * before


def test_lfpc_targets_are_linear_feedback(lfpc_data):
    d = Distiller(tiny(), lfpc_data)
    g = d.gen.get_state()
    frames, targets, _ = d.batch()
    d.gen.set_state(g)  # the same episodes and offsets, read as BC data: no perturbation
    d.data = ExpertData(**{**lfpc_data.__dict__, "method": "bc"})
    nominal, nominal_targets, _ = d.batch()
    delta = (frames - nominal)[:, :4].reshape(-1, 358)
    assert delta.abs().max() > 0
    rows = torch.cdist(nominal[:, :4].reshape(-1, 358), lfpc_data.obs).argmin(1)
    expected = nominal_targets.reshape(-1, 69) + torch.einsum("nad,nd->na", lfpc_data.jacobian[rows].float(), delta)
    torch.testing.assert_close(targets.reshape(-1, 69), expected.clamp(-1, 1), atol=1e-5, rtol=1e-4)


def test_distill_checkpoints_resume_and_track(bc_data, tmp_path):
    cfg = npmp_config(preset="tiny")
    info = {"method": "bc", "expert": "tiny", "action_mapping": "rest", "clips": bc_data.clip_names}
    path, steps = distill(tmp_path, bc_data, cfg, steps=3, info=info, checkpoint_every=2)
    assert steps == 3 and path.name == "step_00000003" and latest_checkpoint(tmp_path / "checkpoints") == path
    with pytest.raises(InputError, match="--resume"):
        distill(tmp_path, bc_data, cfg, steps=5, info=info)
    path, steps = distill(tmp_path, bc_data, cfg, steps=5, info=info, resume=True)
    assert steps == 5 and sorted(p.name for p in (tmp_path / "checkpoints").glob("step_*")) == ["step_00000005"]
    assert distill(tmp_path, bc_data, cfg, steps=5, info=info, resume=True) == (path, 5)  # nothing to do
    agent = make_agent(str(tmp_path))
    assert isinstance(agent, NPMPAgent) and isinstance(load_tracker(str(tmp_path)), NPMPAgent)
    assert agent.info["steps"] == 5 and agent.info["expert"] == "tiny"
    obs = bc_data.obs[:6].numpy()
    zs = agent.track_z(obs)
    assert zs.shape == (5, 4) and agent.act(obs[0], zs[0]).shape == (69,) and agent.act(obs, zs[0]).shape == (6, 69)

    with pytest.raises(InputError, match="z: expected"):
        agent.act(obs, zs[:2])
    with pytest.raises(PromptError, match="no reward prompt"):
        agent.reward_z("move-ego-0-0")
    with pytest.raises(CheckpointError, match="NPMP checkpoint tracks clips"):
        load_checkpoint(path)
    with pytest.raises(ConfigError, match="npmp.alpha"):
        npmp_config({"alpha": 1.0})


def test_cli_distill_resume_track_and_eval(bfm, library, tmp_path):
    from typer.testing import CliRunner

    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.cli.app import app
    from motions.clip import save_clip

    expert = save_checkpoint(tmp_path / "bfm", bfm.model, bfm.config)
    clips = tmp_path / "clips"
    for clip in library.clips:
        save_clip(clip, clips / f"{clip.name}.npz")
    run = tmp_path / "npmp"
    base = ["npmp", "distill", str(expert), "--motions", str(clips), "--out", str(run), "--method", "lfpc",
            "--preset", "tiny", "--max-steps", "3", "--checkpoint-every", "1"]
    res = CliRunner().invoke(app, base + ["--steps", "2"])
    assert res.exit_code == 0, res.output
    assert (run / "data.safetensors").is_file() and (run / "checkpoints" / "step_00000002").is_dir()
    assert '"step": 1' in (run / "metrics.jsonl").read_text()
    res = CliRunner().invoke(app, base + ["--steps", "3", "--resume"])
    assert res.exit_code == 0 and "3 gradient steps" in res.output, res.output
    res = CliRunner().invoke(app, [a if a != "lfpc" else "bc" for a in base] + ["--steps", "4", "--resume"])
    assert res.exit_code == 1 and "holds lfpc data" in res.output
    res = CliRunner().invoke(app, ["track", str(run), str(clips / "arm_swing.npz")])
    assert res.exit_code == 0 and "tracking success" in res.output and "EMD" in res.output, res.output
    res = CliRunner().invoke(app, ["npmp", "eval", str(run), "--motions", str(clips), "--out", str(tmp_path / "ev")])
    assert res.exit_code == 0, res.output
    import json

    result = json.loads((tmp_path / "ev" / "results.json").read_text())["npmp"][str(run)]
    assert set(result["clips"]) == {"arm_swing", "stand"} and result["summary"]["train"]["clips"] == 2
    assert all(c["relative_emd"] > 0 for c in result["clips"].values())


def test_relative_to_expert_by_hand():
    from fbcpr.apps.npmp.evaluate import relative_to_expert

    npmp = {"a": {"emd": 2.0, "success": 0.0}, "b": {"emd": 1.0, "success": 1.0}}
    expert = {"a": {"emd": 1.0, "success": 1.0}, "b": {"emd": 1.5, "success": 1.0}}
    out = relative_to_expert(npmp, expert, train_clips=["a"])
    assert out["clips"]["a"]["split"] == "train" and out["clips"]["b"]["split"] == "held_out"
    assert out["clips"]["a"]["relative_emd"] == 0.5 and out["clips"]["b"]["relative_emd"] == 1.5
    assert out["summary"]["all"] == {"clips": 2, "emd": 1.5, "emd_expert": 1.25, "relative_emd_median": 1.0,
                                     "success": 0.5, "success_expert": 1.0}


def test_latent_optimisation_fits_the_expert_actions(bc_data):
    from fbcpr.apps.npmp.latent_opt import optimise_latents

    model = tiny()
    model.obs_normalizer.update(bc_data.obs)
    states, actions = bc_data.obs[:5], bc_data.action[:5]
    z0 = model.encode(states)
    z0 = torch.cat([z0, z0[-1:]])
    z, before, after = optimise_latents(model, states, actions, z0, steps=50)
    assert z.shape == z0.shape and after < before
    assert all(p.requires_grad for p in model.parameters())
    with pytest.raises(ValueError, match="same T"):
        optimise_latents(model, states, actions[:3], z0)


def test_a_stop_signal_ends_distillation_with_a_checkpoint(bc_data, tmp_path, default_sigint):
    import os
    import signal

    def interrupt(step: int, metrics: dict) -> None:
        if step == 2:
            os.kill(os.getpid(), signal.SIGINT)

    path, steps = distill(tmp_path, bc_data, npmp_config(preset="tiny"), steps=50, info={}, checkpoint_every=10,
                          on_update=interrupt)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    assert steps == 2 and path.name == "step_00000002" and latest_checkpoint(tmp_path / "checkpoints") == path


def test_checkpoint_round_trip_and_corruption(tmp_path):
    from fbcpr.apps.npmp.checkpoint import load_npmp, save_npmp

    model = tiny(alpha=0.0)
    model.obs_normalizer.update(torch.randn(10, 358))
    path = save_npmp(tmp_path / "ck", model, {"method": "bc", "expert": "x"})
    back = load_npmp(path)
    assert back.model.cfg == model.cfg and back.info["expert"] == "x"
    for (k, v), (k2, v2) in zip(model.state_dict().items(), back.model.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    (path / "model.safetensors").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="checksum mismatch"):
        load_npmp(path)


def test_collect_on_another_env_through_make_env():
    from types import SimpleNamespace

    from fbcpr.envs import toy as pm

    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 2, "action_dim": 2}, "env": {"name": "toy"},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    teacher = BFM(FBCPRModel(cfg.model), cfg)
    path = pm.demo_paths(12)["circle-ccw"]
    clip = SimpleNamespace(name="circle", obs=path, n_frames=12, qpos=path.astype(np.float64), qvel=np.zeros((12, 2)))
    data = collect(teacher, SimpleNamespace(clips=[clip], names=["circle"]), "lfpc", max_steps=5,
                   make_env=lambda n, steps: pm.PointMassVectorEnv(n, max_episode_steps=steps))
    assert data.obs.shape == (6, 2) and data.jacobian.shape == (6, 2, 2)
    np.testing.assert_allclose(data.obs[0].numpy(), path[0])  # the rollout starts at the clip's first frame
