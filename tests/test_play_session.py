"""The playground's simulation without a browser: prompts change z on the running body, failures change nothing,
resets and pushes do what they say, the drawn capsules are the MJCF's, and a missing extra is one line."""
from __future__ import annotations

import sys

import mujoco
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from fbcpr.apps.play.body import capsule_mesh
from fbcpr.apps.play.session import Prompts, Session, clip_choices
from fbcpr.cli.app import app
from fbcpr.core.errors import PromptError
from fbcpr.inference.bfm import BFM
from motions.clip import save_clip
from motions.synthetic import default_clips

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def prompts():
    return Prompts(BFM.load("pretrained"))


def test_a_new_prompt_changes_z_and_not_the_body(prompts):
    session = Session(prompts.bfm, prompts.reward("move-ego-0-0"))
    for _ in range(20):
        session.step()
    qpos, qvel = session.qpos.copy(), session.qvel.copy()
    walk = prompts.reward("move-ego-0-2")
    session.use(walk)
    np.testing.assert_array_equal(session.qpos, qpos)  # no reset
    np.testing.assert_array_equal(session.qvel, qvel)
    for _ in range(60):
        reward = session.step()
    np.testing.assert_array_equal(session.source.at(session.t)[0], walk.z[0])
    assert session.source.detail.startswith("stored prompt")
    assert np.linalg.norm(session.qpos[:2] - qpos[:2]) > 0.5 and reward > 0.5  # it walks off, paid by the walk


def test_bad_prompts_raise_before_anything_changes(prompts, tmp_path):
    (tmp_path / "broken.npz").write_bytes(b"no clip")
    for build in (lambda: prompts.reward("no-such-task"), lambda: prompts.goal("no_such_pose"),
                  lambda: prompts.clip(tmp_path / "broken.npz"), lambda: prompts.timeline("jump-2:2,nope:1"),
                  lambda: prompts.timeline("jump-2")):
        with pytest.raises(PromptError):
            build()


def test_goal_clip_and_timeline_sources_score_and_advance(prompts):
    obs = np.zeros(358, np.float32)
    goal = prompts.goal("t_pose")
    assert goal.z.shape == (1, 64) and "B of the pose" in goal.describe(0)
    clip = prompts.clip("walk")
    assert len(clip.z) > 1 and "step 0/" in clip.describe(0)
    assert "ended" in clip.describe(len(clip.z) + 5)
    np.testing.assert_array_equal(clip.at(10**6)[0], clip.z[-1])  # the last z is held past the end
    timeline = prompts.timeline("move-ego-0-2:1,t_pose:1,walk:1")
    assert len(timeline.z) == 90 and timeline.labels == ("move-ego-0-2", "t_pose", "walk")
    z, seg, local = timeline.at(45)
    assert (seg, local) == (1, 15) and "segment 2/3, t_pose" in timeline.describe(45)
    for t in (0, 45, 75):  # each segment's own reward: the task's, goal proximity, clip proximity
        _, seg, local = timeline.at(t)
        value = timeline.scores[seg](local, obs, np.zeros(69, np.float32), np.zeros(76), np.zeros(75))
        assert 0.0 <= value <= 1.0


def test_reset_fall_and_push(prompts):
    session = Session(prompts.bfm, prompts.reward("move-ego-0-0"), seed=1)
    session.reset(fallen=True)
    w, x, y, z = session.qpos[3:7]
    upright = 1 - 2 * (x * x + y * y)  # the pelvis frame's z axis against the world's
    assert session.qpos[2] < 0.6 or upright < 0.7  # low or tilted: a fall's start, not standing
    for _ in range(30):
        session.step()
    assert session.qpos[2] < 0.6  # it lands on the floor
    session.reset()
    assert session.qpos[2] > 0.8 and np.abs(session.qpos[:2]).max() < 1e-9
    before = session.qvel[:2].copy()
    session.push(1.5)
    assert np.linalg.norm(session.qvel[:2] - before) == pytest.approx(1.5)


def test_capsule_mesh_is_the_mjcf_capsule():
    verts, faces = capsule_mesh(0.05, 0.2)
    # every vertex lies at the radius from the axis segment [-0.2, 0.2] on z
    nearest = np.stack([np.zeros(len(verts)), np.zeros(len(verts)), np.clip(verts[:, 2], -0.2, 0.2)], -1)
    np.testing.assert_allclose(np.linalg.norm(verts - nearest, axis=1), 0.05, atol=1e-6)
    assert verts[:, 2].max() == pytest.approx(0.25) and verts[:, 2].min() == pytest.approx(-0.25)
    a, b, c = (verts[faces[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    keep = np.linalg.norm(normal, axis=1) > 1e-12  # the poles' degenerate triangles
    centre = (a + b + c)[keep] / 3
    outward = centre - np.stack([np.zeros(keep.sum()), np.zeros(keep.sum()), np.clip(centre[:, 2], -0.2, 0.2)], -1)
    assert np.all(np.einsum("ij,ij->i", normal[keep], outward) > 0)  # counter-clockwise seen from outside


def test_body_geoms_are_capsules_spheres_boxes_and_a_floor():
    from humanoid_env.model import load_model

    kinds = set(load_model().geom_type.tolist())
    drawn = {mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_BOX,
             mujoco.mjtGeom.mjGEOM_PLANE}
    assert kinds <= {int(k) for k in drawn}


def test_clip_choices(tmp_path):
    clip = default_clips()[0]
    (tmp_path / "sub").mkdir()
    save_clip(clip, tmp_path / "sub" / "a.npz")
    given = tmp_path / "given.npz"
    save_clip(clip, given)
    choices = clip_choices(tmp_path, [given], ["walk"])
    assert choices[str(given)] == str(given) and choices["sub/a.npz"] == str(tmp_path / "sub" / "a.npz")
    assert choices["walk (built-in)"] == "walk"


def test_play_without_its_extra_names_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)
    result = CliRunner().invoke(app, ["play"])
    assert result.exit_code == 1 and 'pip install "fbcpr[play]"' in result.output


def test_play_rejects_a_missing_clip_file(tmp_path):
    result = CliRunner().invoke(app, ["play", "--clip", str(tmp_path / "none.npz")])
    assert result.exit_code == 1 and "none.npz: no such clip file" in result.output


def test_page_pauses_steps_and_keeps_the_prompt_on_failure(prompts):
    from fbcpr.apps.play.page import Playground

    session = Session(prompts.bfm, prompts.reward("move-ego-0-0"))
    page = Playground(session, prompts, ["move-ego-0-0", "move-ego-0-2"], ["t_pose"], {}, port=free_port())
    try:
        assert page.url.startswith("http://127.0.0.1:")
        assert page.tick() and session.steps == 1
        page.paused = True
        assert not page.tick() and session.steps == 1  # paused: drawn, not stepped
        page.step_once = True
        assert page.tick() and session.steps == 2 and not page.step_once  # one step on request
        source = session.source
        page._prompt(lambda: prompts.reward("no-such-task"))
        assert session.source is source and "no\\-such\\-task" in page.message.content
        page._prompt(lambda: prompts.reward("move-ego-0-2"))
        assert session.source.label == "move-ego-0-2" and page.message.content == ""
    finally:
        page.stop()


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_play_starts_a_model_without_reward_states_on_a_goal(tmp_path, monkeypatch):
    from fbcpr.apps.play.page import Playground
    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69}})
    ckpt = save_checkpoint(tmp_path / "no-states", FBCPRModel(cfg.model), cfg)

    def stop_at_once(self, *args, **kwargs):
        raise KeyboardInterrupt  # as Ctrl-C would, once the page is served

    monkeypatch.setattr(Playground, "run", stop_at_once)
    result = CliRunner().invoke(app, ["play", "--model", str(ckpt), "--port", str(free_port())])
    assert result.exit_code == 0, result.output
    assert "http://127.0.0.1:" in result.output and "starts under the goal t_pose" in result.output
