"""Goal poses: named, on the floor, within joint ranges, and holdable under PD control; goals from clips."""
import mujoco
import numpy as np
import pytest

from humanoid_env.model import JOINT_NAMES, NV, load_model
from humanoid_env.observation import observe
from humanoid_env.tasks import GOALS, goal_from_clip, goal_names, goal_obs, goal_qpos
from humanoid_env.tasks.goals import ARMS_FORWARD, HOLD_TOLERANCE, GoalPose, hold_drift, lowest_point, pose_qpos

MODEL = load_model()
PAPER_NAMES = ["t_pose", "t_pose_lower_arms", "t_pose_bow_head", "crouch_high", "crouch_medium", "crouch_low",
               "kneel_left", "zombie", "egyptian", "arms_stretch", "scratching_head", "right_hand_wave"]


def test_at_least_30_goals_with_the_paper_names():
    assert len(goal_names()) >= 30 and len(set(goal_names())) == len(goal_names())
    assert set(PAPER_NAMES) <= set(GOALS)


@pytest.mark.parametrize("name", list(GOALS))
def test_goal_state_is_valid_and_on_the_floor(name):
    q = goal_qpos(name)
    lo, hi = MODEL.jnt_range[1:, 0], MODEL.jnt_range[1:, 1]
    assert q.shape == (76,) and np.all((q[7:] >= lo - 1e-9) & (q[7:] <= hi + 1e-9))
    assert abs(np.linalg.norm(q[3:7]) - 1) < 1e-9
    assert abs(lowest_point(MODEL, q)) < 1e-6
    obs = goal_obs(name)
    assert obs.shape == (358,) and np.all(obs[214:] == 0)  # velocities zero
    np.testing.assert_allclose(obs, observe(MODEL, q, np.zeros(NV)))


def test_no_goal_interpenetrates_itself():
    data = mujoco.MjData(MODEL)
    for name in GOALS:
        data.qpos[:] = goal_qpos(name)
        data.qpos[2] += 10.0  # away from the floor: only self-contacts remain
        mujoco.mj_kinematics(MODEL, data)
        mujoco.mj_collision(MODEL, data)
        depth = max([0.0, *(-data.contact.dist[: data.ncon])])
        assert depth < 0.01, f"{name}: body geoms overlap by {depth:.3f} m"


def test_specs_are_applied():
    q = goal_qpos("zombie")
    assert np.isclose(np.rad2deg(q[7 + JOINT_NAMES.index("L_Shoulder_z")]), -90)
    assert np.isclose(np.rad2deg(q[7 + JOINT_NAMES.index("R_Shoulder_z")]), 90)
    heights = [goal_qpos(g)[2] for g in ("crouch_low", "crouch_medium", "crouch_high", "t_pose")]
    assert heights == sorted(heights) and heights[-1] > 0.9
    assert goal_qpos("lie_back")[2] < 0.2
    q = goal_qpos("t_pose")
    q[0] = 99.0  # callers get copies: the cached goal stays intact
    assert goal_qpos("t_pose")[0] == 0.0


def test_all_goals_hold_under_pd_control():
    drift = {name: hold_drift(goal_qpos(name), seconds=2.0).max() for name in GOALS}
    bad = {k: round(v, 2) for k, v in drift.items() if v > HOLD_TOLERANCE}
    assert not bad, f"goal poses that do not hold: {bad}"


def test_hold_check_catches_an_unbalanced_pose():
    """Arms forward without balancing over the ankles topples: the stability check must see that."""
    assert hold_drift(pose_qpos(GoalPose(ARMS_FORWARD)), seconds=2.0).max() > 3 * HOLD_TOLERANCE


def test_goal_from_any_clip_frame():
    rng = np.random.default_rng(0)
    qpos = np.tile(goal_qpos("a_pose"), (5, 1))
    qpos[:, 7:] += rng.normal(scale=0.05, size=(5, 69))

    class Clip:  # anything with a (T, 76) qpos works, e.g. motions.clip.Clip
        pass

    clip = Clip()
    clip.qpos = qpos
    for frame in (0, 3, -1):
        np.testing.assert_allclose(goal_from_clip(clip, frame), observe(MODEL, qpos[frame], np.zeros(NV)))
    with pytest.raises(ValueError, match="out of range"):
        goal_from_clip(clip, 5)
    with pytest.raises(ValueError, match="76"):
        goal_from_clip(qpos[:, :70], 0)


def test_goal_from_a_synthetic_motion_clip():
    from motions.synthetic import stand

    clip = stand(seconds=1.0)
    np.testing.assert_allclose(goal_from_clip(clip, 10)[:214], clip.obs[10, :214], atol=1e-5)


def test_unknown_goal_and_joint_raise():
    with pytest.raises(ValueError, match="t_pose"):
        goal_qpos("moonwalk")
    with pytest.raises(ValueError, match="unknown joint"):
        pose_qpos(GoalPose({"L_Elbow_q": 10}))
