"""Tracking refined by rollouts: one z per window, never worse than zero-shot on its planning objective, the
executed states replayable from the z's, bad settings refused, and the CLI's cost line."""
from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import tiny_humanoid_checkpoint
from fbcpr.cli.app import app
from fbcpr.core.errors import PromptError
from fbcpr.inference.bfm import BFM
from fbcpr.inference.track_refine import Receding, refine_track
from fbcpr.metrics import d_smpl
from humanoid_env.model import load_model
from humanoid_env.render import renderer_available
from humanoid_env.vector import VectorHumanoidEnv
from motions.clip import from_qpos, save_clip

torch.set_num_threads(1)
QUICK = Receding(candidates=4, rounds=2, window=4, horizon=6, seed=3)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return tiny_humanoid_checkpoint(tmp_path_factory.mktemp("track_refine"), "tiny", seed=0)


@pytest.fixture(scope="module")
def bfm(ckpt) -> BFM:
    return BFM.load(ckpt)


@pytest.fixture(scope="module")
def clip():
    """11 frames of an arm rising from the rest pose: 10 steps, windows of 4, 4 and 2."""
    qpos = np.tile(load_model().qpos0, (11, 1))
    qpos[:, 7 + 45] = np.linspace(0.0, 1.0, 11)
    return from_qpos(qpos, name="arm_rise")


def replay(bfm: BFM, clip, zs: np.ndarray) -> np.ndarray:
    """The states the z's reach from the clip's first state, played one step at a time."""
    env = VectorHumanoidEnv(1, max_episode_steps=len(zs) + 1, num_threads=1, action_mapping=bfm.action_mapping)
    o, _ = env.reset(options={"qpos": clip.qpos[:1], "qvel": clip.qvel[:1]})
    states = [o[0]]
    for z in zs:
        o, _, _, _, info = env.step(np.asarray(bfm.act(o, z[None]), dtype=np.float32))
        states.append(info["final_obs"][0])
    env.close()
    return np.stack(states)


def test_one_centre_per_window_and_one_z_per_step(bfm, clip):
    res = bfm.prompt.track_refined(clip, QUICK)
    d = bfm.z_dim
    assert res.window_z.shape == res.window_z0.shape == (3, d) and res.plan_cost.shape == (3,)
    assert res.zs.shape == (10, d) and res.obs.shape == (11, bfm.obs_dim) and res.diverged_at is None
    assert np.allclose(np.linalg.norm(res.zs, axis=1), np.sqrt(d), rtol=1e-4)
    # 2 rounds of 4 and the last mean a window, and the B-given z's scored apart after the first (a warm start)
    assert res.rollouts == 3 * (4 * 2 + 1) + 2 and res.seconds > 0 and res.cost == res.seconds / (10 / 30)
    np.testing.assert_array_equal(bfm.prompt.track(clip, refine=QUICK), res.zs)  # the same search, seeded
    # the z's returned are the z's executed: played again from the first state they reach the same states
    np.testing.assert_allclose(replay(bfm, clip, res.zs), res.obs, atol=1e-4)


def test_the_search_never_costs_more_than_the_B_given_zs(bfm, clip):
    res = bfm.prompt.track_refined(clip, QUICK)
    assert np.all(res.plan_cost <= res.plan_cost0) and np.any(res.plan_cost < res.plan_cost0)
    # the B-given candidate of the first window is zero-shot tracking: its cost is that of the B-given z's
    zs0 = bfm.prompt.track(clip)
    zero = replay(bfm, clip, zs0[:6])
    assert res.plan_cost0[0] == pytest.approx(d_smpl(zero[1:], clip.obs[1:7]).mean(), rel=1e-4)
    # one window as long as the clip: the executed trajectory is the plan, so tracking can only get better
    whole = Receding(candidates=6, rounds=2, window=10, horizon=10, seed=0)
    one = bfm.prompt.track_refined(clip, whole)
    refined_cost = d_smpl(one.obs[1:], clip.obs[1:]).mean()
    zero_cost = d_smpl(replay(bfm, clip, zs0)[1:], clip.obs[1:]).mean()
    assert one.window_z.shape == (1, bfm.z_dim) and refined_cost <= zero_cost + 1e-6


def test_other_starts_and_a_position_term_keep_the_B_given_zs_a_candidate(bfm, clip):
    # leads and lookaheads add starting centres scored beside z̄ and the warm start; the position term changes the
    # planning cost, and the kept candidate never costs more than the B-given one on it
    wide = Receding(candidates=4, rounds=2, window=4, horizon=6, seed=3, position_weight=10.0, leads=(2,),
                    lookaheads=(1, 4))
    res = bfm.prompt.track_refined(clip, wide)
    assert np.all(res.plan_cost <= res.plan_cost0)
    # a window: z̄, the warm start after the first, one lead and two lookaheads, then 2 rounds of 4 and the last mean
    assert res.rollouts == 3 * (1 + 3 + 4 * 2 + 1) + 2
    np.testing.assert_allclose(replay(bfm, clip, res.zs), res.obs, atol=1e-4)
    # the first window's B-given cost is zero-shot tracking's d_smpl plus 10 x its per-step body-position error
    zero = replay(bfm, clip, bfm.prompt.track(clip)[:6])
    pos = np.linalg.norm((zero[1:, 1:70] - clip.obs[1:7, 1:70]).reshape(6, 23, 3), axis=-1).mean(-1)
    assert res.plan_cost0[0] == pytest.approx((d_smpl(zero[1:], clip.obs[1:7]) + 10.0 * pos).mean(), rel=1e-4)
    with pytest.raises(PromptError, match="alternatives must be"):
        refine_track(bfm, clip.obs, (clip.qpos[0], clip.qvel[0]), bfm.prompt.track(clip), QUICK,
                     alternatives=np.ones((2, 3, bfm.z_dim)))


@pytest.mark.parametrize("refine, message", [
    (Receding(window=0), "window must be a positive integer"),
    (Receding(window=8, horizon=4), "horizon (4) must be at least the window (8)"),
    (Receding(candidates=1), "candidates must be an integer >= 2, got 1"),
    (Receding(rounds=0), "rounds must be an integer >= 1, got 0"),
    (Receding(sigma=float("nan")), "sigma must be a finite number"),
    (Receding(position_weight=-1.0), "position_weight must be >= 0"),
    (Receding(leads=(0,)), "leads must be positive integers"),
    (Receding(lookaheads=(2, True)), "lookaheads must be positive integers"),
    (1, "candidates a round must be an integer >= 2"),
    (-3, "candidates a round must be an integer >= 2"),
    (True, "candidates a round must be an integer >= 2"),
])
def test_bad_settings_raise_the_prompt_error(bfm, clip, refine, message):
    with pytest.raises(PromptError, match=re.escape(message)):
        bfm.prompt.track(clip, refine=refine)


def test_bare_observations_cannot_be_refined(bfm, clip):
    with pytest.raises(PromptError, match="needs a Clip or a clip file"):
        bfm.prompt.track(clip.obs, refine=4)
    with pytest.raises(PromptError, match="zs0 must be one z per step"):
        refine_track(bfm, clip.obs, (clip.qpos[0], clip.qvel[0]), np.ones((3, bfm.z_dim)), QUICK)


def test_cli_refines_and_prints_its_cost(ckpt, clip, tmp_path):
    path, video = save_clip(clip, tmp_path / "arm_rise.npz"), tmp_path / "track.mp4"
    args = ["track", str(ckpt), str(path), "--refine", "3", "--refine-rounds", "1", "--refine-position-weight", "5",
            "--refine-leads", "2", "--refine-lookaheads", "1,4", "--refine-window", "4", "--refine-horizon", "5"]
    res = CliRunner().invoke(app, args + (["--video", str(video)] if renderer_available() else []))
    assert res.exit_code == 0, res.output
    if renderer_available():  # the states the search executed, rendered beside the reference
        import imageio.v2 as imageio

        frames = imageio.mimread(video)
        assert len(frames) == 11  # the first state and one per step
    assert "(refined)" in res.output and "11 / 11" in res.output and "MPJPE" in res.output
    line = re.search(r"refinement cost: ([\d.]+) s of compute for ([\d.]+) s of\s+motion, ([\d.]+) s per second",
                     res.output)
    assert line is not None, res.output
    assert float(line.group(2)) == pytest.approx(10 / 30, abs=0.05) and float(line.group(3)) > 0
    bad = CliRunner().invoke(app, args[:-1] + ["2"])
    assert bad.exit_code != 0 and "horizon (2) must be at least the window (4)" in bad.output
    bad = CliRunner().invoke(app, [a if a != "1,4" else "1,x" for a in args])
    assert bad.exit_code != 0 and "--refine-lookaheads" in bad.output and "'1,x'" in bad.output
    bad = CliRunner().invoke(app, [a if a != "2" else "0" for a in args])
    assert bad.exit_code != 0 and "leads must be positive integers" in bad.output
