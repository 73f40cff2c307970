"""Behaviour checks: each family's rule read off bodies we know (named poses held still, a pose lifted into the
air, a body carried at a set velocity), the floors run through the real rollouts, and the CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from fbcpr.cli.app import app
from fbcpr.core.errors import InputError
from fbcpr.eval import behaviours as B
from fbcpr.eval.agents import RandomAgent, ZeroAgent
from humanoid_env.model import CONTROL_HZ, NV, load_model
from humanoid_env.observation import observe
from humanoid_env.tasks.goals import goal_qpos

T = 3 * CONTROL_HZ


def held(qpos: np.ndarray, qvel: np.ndarray | None = None, steps: int = T) -> B.Trace:
    """One episode of a body held in `qpos` (moving at `qvel`) for `steps` steps."""
    qv = np.zeros((steps, NV)) if qvel is None else np.tile(qvel, (steps, 1))
    obs = observe(load_model(), np.tile(qpos, (steps, 1)), qv).astype(np.float32)
    return B.Trace(obs[:, None])


def passes(family: str, trace: B.Trace) -> bool:
    judge = {f.name: f.judge for f in B.FAMILIES}[family]
    assert judge is not None
    ok, measures = judge(trace)
    assert ok.shape == (1,) and all(v.shape == (1,) for v in measures.values())
    return bool(ok[0])


@pytest.mark.parametrize("pose, family", [("t_pose", "stand"), ("hands_up", "hands_up"), ("sit_on_ground", "sit"),
                                          ("lie_back", "lie_face_up"), ("crouch_low", "crouch"),
                                          ("t_pose", "get_up")])
def test_a_named_pose_held_passes_its_family_and_no_other_posture(pose: str, family: str) -> None:
    trace = held(goal_qpos(pose))
    assert passes(family, trace)
    postures = {"sit", "lie_face_up", "crouch", "hands_up", "jump", "walk", "run", "spin"} - {family}
    assert not [f for f in postures if passes(f, trace)]


@pytest.mark.parametrize("pose", ["kneel_both", "lie_front", "crouch_high"])
def test_near_misses_fail(pose: str) -> None:
    """Kneeling upright is not sitting, lying face down is not face up, a shallow crouch is not a crouch."""
    trace = held(goal_qpos(pose))
    assert not passes({"kneel_both": "sit", "lie_front": "lie_face_up", "crouch_high": "crouch"}[pose], trace)


def test_jump_needs_flight_and_height_after_the_first_second() -> None:
    stand = goal_qpos("t_pose")
    qpos = np.tile(stand, (T, 1))
    lift = np.zeros(T)
    lift[45:55] = 0.25 * np.sin(np.linspace(0, np.pi, 10))  # a 0.25 m hop at 1.5 s
    qpos[:, 2] += lift
    obs = observe(load_model(), qpos, np.zeros((T, NV))).astype(np.float32)
    assert passes("jump", B.Trace(obs[:, None]))
    low = np.tile(stand, (T, 1))
    low[:, 2] += lift * 0.4  # 0.10 m: off the ground, not high enough
    assert not passes("jump", B.Trace(observe(load_model(), low, np.zeros((T, NV))).astype(np.float32)[:, None]))
    early = np.tile(stand, (T, 1))
    early[:20, 2] += 0.5  # dropped from 0.5 m: a fall start, not a jump
    assert not passes("jump", B.Trace(observe(load_model(), early, np.zeros((T, NV))).astype(np.float32)[:, None]))


def test_feet_raised_while_lying_are_no_flight() -> None:
    """A body on its back with its feet in the air has every foot off the floor, but it is not jumping."""
    lying = np.tile(goal_qpos("lie_back"), (T, 1))
    lying[:, 2] += 0.15  # the whole body, feet included, 0.15 m up
    trace = B.Trace(observe(load_model(), lying, np.zeros((T, NV))).astype(np.float32)[:, None])
    feet_up = np.all([trace.z(b) > B.standing_heights()[b] + B.FLIGHT_CLEARANCE for b in B.FEET], axis=0)
    assert feet_up[CONTROL_HZ:].all()  # the feet would count as a flight by height alone
    ok, m = {f.name: f.judge for f in B.FAMILIES}["jump"](trace)  # type: ignore[misc]
    assert m["flight_steps"][0] == 0 and not ok[0]


@pytest.mark.parametrize("vx, vy, walk, run", [(2.0, 0.0, True, False), (4.0, 0.0, False, True),
                                               (0.5, 0.0, False, False), (0.0, 2.0, False, False),
                                               (-2.0, 0.0, False, False)])
def test_walk_and_run_read_speed_along_the_facing(vx: float, vy: float, walk: bool, run: bool) -> None:
    qvel = np.zeros(NV)
    qvel[:2] = vx, vy  # the t_pose faces +x
    trace = held(goal_qpos("t_pose"), qvel)
    assert passes("walk", trace) is walk and passes("run", trace) is run
    ok, m = {f.name: f.judge for f in B.FAMILIES}["walk"](trace)  # type: ignore[misc]
    assert m["speed"][0] == pytest.approx(vx, abs=0.05)


def test_spin_reads_the_yaw_rate_and_its_sign() -> None:
    qvel = np.zeros(NV)
    qvel[5] = 3.0  # about the vertical, rad/s
    assert passes("spin", held(goal_qpos("t_pose"), qvel))
    qvel[5] = -3.0
    assert not passes("spin", held(goal_qpos("t_pose"), qvel))


def test_families_by_name_and_bad_input() -> None:
    assert [f.name for f in B.families(["jump", "stand"])] == ["stand", "jump"]
    with pytest.raises(InputError, match="unknown behaviour family leap.*get_up"):
        B.families(["leap"])
    with pytest.raises(InputError, match="episodes x steps must be 1-9,600.*got 1000 x 60"):
        B.check({"zero": ZeroAgent()}, ["stand"], episodes=1000, steps=60)
    with pytest.raises(InputError, match="got 2 x 100000"):
        B.check({"zero": ZeroAgent()}, ["stand"], episodes=2, steps=100_000)
    with pytest.raises(InputError, match="steps must be >= 60"):
        B.check({"zero": ZeroAgent()}, ["stand"], episodes=1, steps=30)


def test_floor_runs_once_per_start_and_is_judged_for_every_family(tmp_path) -> None:
    res = B.check({"zero": ZeroAgent()}, ["stand", "get_up", "goal_poses"], episodes=2, steps=60, seed=3,
                  out=tmp_path, show_progress=False)
    fam = res["families"]
    assert fam["stand"]["agents"]["zero"]["standing"]["pass"] == 1.0  # zero action holds a quiet standing start
    assert set(fam["stand"]["agents"]["zero"]) == {"pushed", "standing"}  # the stand family's own start, and beside
    assert fam["get_up"]["agents"]["zero"]["fall"]["pass"] == 0.0  # and does not rise from a fall
    assert set(fam["get_up"]["agents"]["zero"]) == {"fall", "standing"}
    assert not fam["get_up"]["passed"]
    poses = fam["goal_poses"]["agents"]["zero"]["standing"]["poses"]
    assert len(poses) == 33 and poses["t_pose"]["final_distance"] < poses["lie_back"]["final_distance"]
    assert res["summary"]["of"] == 3
    saved = json.loads((tmp_path / "behaviours.json").read_text())
    assert saved["summary"] == res["summary"] and saved["margin"] == B.MARGIN
    assert "poses_reached" not in fam["goal_poses"]  # the zero floor is not compared with itself
    sheets = res["sheets"]
    if isinstance(sheets, list):
        assert sorted(p.rsplit("/", 1)[1] for p in sheets) == ["get_up.png", "goal_poses.png", "stand.png"]
        from PIL import Image

        assert Image.open(sheets[0]).size == (7 * B.TILE[0], B.TILE[1] + 18)
    else:
        assert sheets.startswith("no contact sheets: no OpenGL renderer")


def test_cli_behaviours_suite(tmp_path) -> None:
    runner = CliRunner()
    out = tmp_path / "beh"
    res = runner.invoke(app, ["eval", "zero", "--suite", "behaviours", "--tasks", "stand,jump", "--episodes", "1",
                              "--steps", "60", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "zero passes 0 of 2 families" in " ".join(res.output.split())  # judged against random alone
    assert set(json.loads((out / "behaviours.json").read_text())["families"]) == {"stand", "jump"}
    bad = runner.invoke(app, ["eval", "zero", "--suite", "behaviours", "--fall-prob", "0.2"])
    assert bad.exit_code != 0 and "--fall-prob" in bad.output
    unknown = runner.invoke(app, ["eval", "zero", "--suite", "behaviours", "--tasks", "leap", "--out", str(out)])
    assert unknown.exit_code != 0 and "unknown behaviour family leap" in " ".join(unknown.output.split())


def test_a_diverged_episode_fails_its_family(monkeypatch) -> None:
    """The env restarts an env whose simulation diverged (from a quiet standing start): its episode must not pass
    as the new start's behaviour."""
    from humanoid_env.vector import VectorHumanoidEnv

    real = VectorHumanoidEnv.step
    calls = {"n": 0}

    def step(self, action):
        out = real(self, action)
        calls["n"] += 1
        if calls["n"] == 10:
            out[4]["diverged"][0] = True  # the first standing episode
        return out

    monkeypatch.setattr(VectorHumanoidEnv, "step", step)
    res = B.check({"zero": ZeroAgent()}, ["stand"], episodes=2, steps=60, show_progress=False)
    standing = res["families"]["stand"]["agents"]["zero"]["standing"]
    assert standing["pass"] == 0.5 and standing["diverged"] == 1
    assert res["families"]["stand"]["agents"]["zero"]["pushed"]["diverged"] == 0


def test_goal_poses_reached_are_compared_with_the_floors() -> None:
    """A model that only stands still reaches the T-poses (the rest pose is one), but no better than zero action."""
    res = B.check({"still": ZeroAgent(), "zero": ZeroAgent(), "random": RandomAgent(0)}, ["goal_poses"], episodes=1,
                  steps=60, show_progress=False)
    goals = res["families"]["goal_poses"]
    assert "t_pose" in goals["poses_reached"] and "lie_back" not in goals["poses_reached"]
    assert goals["reached_not_above_floors"] == goals["poses_reached"]
    still = goals["agents"]["still"]["standing"]
    assert still["pass"] > 0 and goals["success_above_floors"] == 0.0 and not goals["passed"]  # all the floor's
    assert goals["scores"]["still"] == 0.0 and goals["scores"]["zero"] == still["pass"]


@pytest.mark.parametrize("score, floors, need, passed", [
    (1.0, [1.0, 0.0], 0.5, False),      # equal to the zero floor: the quiet stand of the old stand family
    (0.625, [0.0, 0.625], 0.5, False),  # equal to the random floor: lying face up
    (0.875, [0.0, 0.625], 0.5, True),   # two episodes in eight above the better floor
    (0.75, [0.0, 0.625], 0.5, False),   # one episode above it is within the noise
    (0.375, [0.0, 0.0], 0.5, False),    # far above both floors but short of the family's need
    (0.3, [0.05, 0.0], 0.3, True),      # the goal family's need, a margin of 0.25 over the floor
    (0.3, [0.06, 0.0], 0.3, False),
    (0.5, [], 0.5, True),               # no floor beside it: the need alone
])
def test_a_family_passes_only_above_both_floors_by_the_margin(score, floors, need, passed) -> None:
    assert B.MARGIN == 0.25
    assert B.beats_floors(score, floors, need) is passed


def test_an_agent_that_does_what_a_floor_does_passes_no_family(tmp_path) -> None:
    """Zero action judged against itself and random actions: every score equals a floor's, so nothing passes, though
    zero action meets the stand rule from quiet starts; the table shows the model, both floors and the margin."""
    from rich.console import Console

    res = B.check({"still": ZeroAgent(), "zero": ZeroAgent(), "random": RandomAgent(0)},
                  ["stand", "lie_face_up", "get_up"], episodes=2, steps=60, seed=5, show_progress=False)
    fam = res["families"]
    assert fam["stand"]["agents"]["still"]["standing"]["pass"] == 1.0
    assert all(e["scores"]["still"] == e["scores"]["zero"] and not e["passed"] for e in fam.values())
    assert res["summary"]["families_passed"] == 0
    console = Console(width=200, record=True)
    console.print(B.table(res))
    text = console.export_text()
    header = next(line for line in text.splitlines() if "family" in line)
    assert all(col in header for col in ("still", "zero", "random", "above floors", "other start", "passed"))
    assert "pushed" in text and "+0.00" in text and "0.25 more than each floor" in " ".join(text.split())


def test_the_pushed_start_topples_zero_action() -> None:
    """The stand family's start is one the zero action cannot hold, so a model passes it by balancing."""
    res = B.check({"zero": ZeroAgent()}, ["stand"], episodes=8, steps=300, seed=7, show_progress=False)
    stand = res["families"]["stand"]["agents"]["zero"]
    assert stand["standing"]["pass"] == 1.0 and stand["pushed"]["pass"] <= 0.25


def test_refine_searches_each_family_prompt_from_its_own_kind_of_start() -> None:
    """With refine, a family is judged under its task prompt refined by rollouts (fbcpr.inference.refine) from starts
    of its own kind: get_up's stand prompt from falls, stand's from standing, each a z of its own."""
    from fbcpr import BFM
    from fbcpr.cli.eval_cmd import reward_refinement

    bfm = BFM.pretrained()
    fams = B.families(["stand", "get_up"])
    refinement = reward_refinement(1, steps=30, seed=0)
    zs, starts, key_of = B._prompts(bfm, fams, refinement, seed=0)
    assert key_of == {"stand": "move-ego-0-0@pushed", "get_up": "move-ego-0-0@fall"}
    assert starts == {"move-ego-0-0@pushed": ["standing", "pushed"], "move-ego-0-0@fall": ["standing", "fall"]}
    zero_shot = bfm.prompt.reward("move-ego-0-0")
    assert not np.allclose(zs["move-ego-0-0@pushed"], zs["move-ego-0-0@fall"])
    assert all(np.linalg.norm(z) == pytest.approx(np.sqrt(bfm.z_dim), rel=1e-3) for z in zs.values())
    assert any(not np.allclose(z, zero_shot) for z in zs.values())  # the search moved off the zero-shot z
    assert B.refine_env_steps(fams, refinement) == 2 * (16 + 1) * B.REFINE_STARTS * 30
    assert B.refine_env_steps(fams, None) == 0
    assert B.estimate_env_steps(fams, 2, 60, model=True, refined=True) == 4 * 2 * 60
    assert B.estimate_env_steps(fams, 2, 60, model=True) == 3 * 2 * 60  # one zero-shot prompt from three starts
    assert B.estimate_env_steps(fams, 2, 60, model=False) == 3 * 2 * 60


def test_cli_refine_is_for_the_behaviour_suite_only() -> None:
    res = CliRunner().invoke(app, ["eval", "zero", "--suite", "goal", "--refine", "2"])
    assert res.exit_code != 0 and "--refine applies to --suite behaviours" in " ".join(res.output.split())
