"""Reward registry: paper task names, parsing, composition, errors, and known values on hand-built states."""
import re

import mujoco
import numpy as np
import pytest

from humanoid_env.model import BODY_NAMES, NV, load_model
from humanoid_env.observation import BODY_POS, OBS_DIM, observe
from humanoid_env.tasks import CATEGORIES, TASKS, get_reward, goal_qpos, list_families, task_category
from humanoid_env.tasks.features import Features
from humanoid_env.tasks.goals import ARMS_DOWN, ARMS_FORWARD, GoalPose, _merge, pose_qpos
from humanoid_env.tasks.rewards import RaiseArms

MODEL = load_model()

TABLE_18 = (
    ["move-ego-0-0", "move-ego-low-0-0", "handstand", "move-ego-0-2", "move-ego-0-4", "move-ego-90-2", "move-ego-90-4",
     "move-ego--90-2", "move-ego--90-4", "move-ego-180-2", "move-ego-180-4", "move-ego-low-0-2", "move-ego-low-90-2",
     "move-ego-low--90-2", "move-ego-low-180-2", "jump-2", "rotate-x-5-0.8", "rotate-x--5-0.8", "rotate-y-5-0.8",
     "rotate-y--5-0.8", "rotate-z-5-0.8", "rotate-z--5-0.8"]
    + [f"raisearms-{a}-{b}" for a in "lmh" for b in "lmh"]
    + ["crouch-0", "sitonground", "lieonground-up", "lieonground-down", "split-0.5", "split-1"]
    + [f"crawl-{h}-{s}-{f}" for f in "ud" for h in ("0.4", "0.5") for s in ("0", "2")]
)
TABLE_25 = [f"move-ego-0-2-raisearms-{a}-{b}" for a in "lmh" for b in "lmh"]


def state(qpos, lin=(0.0, 0.0, 0.0), ang=(0.0, 0.0, 0.0)):
    """Observation of qpos with a rigid root velocity (world linear, local angular)."""
    qvel = np.zeros(NV)
    qvel[:3], qvel[3:6] = lin, ang
    return observe(MODEL, qpos, qvel)


def yawed(qpos, deg):
    q = qpos.copy()
    rot = np.empty(4)
    mujoco.mju_axisAngle2Quat(rot, np.array([0.0, 0.0, 1.0]), np.deg2rad(deg))
    mujoco.mju_mulQuat(q[3:7], rot, qpos[3:7])
    return q


STAND = goal_qpos("a_pose")
R = {}  # memo of rewards by name


def r(name, obs):
    fn = R.setdefault(name, get_reward(name))
    return float(fn(obs))


def test_every_paper_task_exists_under_its_name():
    assert len(TABLE_18) == 45 and set(TABLE_18 + TABLE_25) == set(TASKS)
    for name in TASKS:
        assert get_reward(name).name == name
        assert CATEGORIES[name] == task_category(name)
    counts = {c: list(CATEGORIES.values()).count(c) for c in set(CATEGORIES.values())}
    assert counts == {"Stand": 2, "Handstand": 1, "Locomotion": 8, "LocomLow": 4, "Jump": 1, "Rotation": 6,
                      "RaiseArms": 9, "On-Ground": 6, "Crawl": 8, "Composite": 9}


def test_values_in_unit_interval_on_random_and_extreme_observations():
    rng = np.random.default_rng(0)
    obs = np.concatenate([rng.normal(size=(200, OBS_DIM)), 50 * rng.normal(size=(50, OBS_DIM))]).astype(np.float32)
    for name in TASKS + ("headstand", "move-ego-45-3", "jump-1.7", "head-1.4"):
        v = get_reward(name)(obs)
        assert v.shape == (250,) and v.dtype == np.float32
        assert np.all((v >= 0) & (v <= 1)), name


def test_standing_and_lying():
    stand, lie_up, lie_down = state(STAND), state(goal_qpos("lie_back")), state(goal_qpos("lie_front"))
    assert r("move-ego-0-0", stand) > 0.95 and r("lieonground-up", stand) < 0.05
    assert r("lieonground-up", lie_up) > 0.95 and r("move-ego-0-0", lie_up) < 0.05
    assert r("lieonground-down", lie_down) > 0.95 and r("lieonground-up", lie_down) < 0.05
    assert r("lieonground-down", lie_up) < 0.05


def test_locomotion_direction_and_speed_in_the_heading_frame():
    for yaw in (0.0, 70.0, -150.0):
        q = yawed(STAND, yaw)
        c, s = np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))
        forward, left = state(q, lin=(2 * c, 2 * s, 0)), state(q, lin=(-2 * s, 2 * c, 0))
        assert r("move-ego-0-2", forward) > 0.95
        assert r("move-ego-0-4", forward) < r("move-ego-0-2", forward) - 0.3
        assert r("move-ego-180-2", forward) < 0.01 and r("move-ego-90-2", forward) < 0.05
        assert r("move-ego-0-0", forward) < 0.01
        assert r("move-ego-90-2", left) > 0.95 and r("move-ego--90-2", left) < 0.01
        assert r("move-ego-45-2.83", state(q, lin=(2 * c - 2 * s, 2 * s + 2 * c, 0))) > 0.9


def test_low_locomotion_prefers_a_low_pelvis():
    crouch = goal_qpos("crouch_low")
    assert r("move-ego-low-0-0", state(crouch)) > 0.9 > 0.3 > r("move-ego-low-0-0", state(STAND))
    assert r("move-ego-low-0-2", state(crouch, lin=(2, 0, 0))) > 0.9


def test_arm_heights():
    cases = {"a_pose": "l-l", "t_pose": "m-m", "arms_stretch": "h-h", "left_arm_up": "h-l", "right_arm_up": "l-h"}
    for goal, want in cases.items():
        obs = state(goal_qpos(goal))
        scores = {f"{a}-{b}": r(f"raisearms-{a}-{b}", obs) for a in "lmh" for b in "lmh"}
        assert scores[want] > 0.95, (goal, scores)
        assert max(v for k, v in scores.items() if k != want) < 0.1, (goal, scores)
    moving = state(goal_qpos("arms_stretch"), lin=(1.5, 0, 0))
    assert 0.45 < r("raisearms-h-h", moving) < 0.55  # needless movement halves the reward


def test_head_height_pays_more_for_every_posture_further_up():
    poses = ["lie_front", "sit_on_ground", "kneel_both", "crouch_low", "crouch_medium", "crouch_high"]
    states = np.stack([state(goal_qpos(p)) for p in poses] + [state(STAND)])
    heads = Features(states).z("Head")
    values = get_reward("head-1.4")(states)
    order = np.argsort(heads)
    assert np.all(np.diff(values[order]) > 0), dict(zip(poses + ["stand"], values))
    assert values[0] < 0.2 and values[-1] == 1.0
    assert abs(values[2] - heads[2] / 1.4) < 1e-5  # linear below 1.4 m (kneel_both)
    assert task_category("head-1.4") == "Stand"


def test_ground_poses():
    assert r("crouch-0", state(goal_qpos("crouch_low"))) > 0.9
    assert r("crouch-0", state(STAND)) < 0.1 and r("crouch-0", state(goal_qpos("sit_on_ground"))) < 0.05
    # standing on bent knees is not a crouch: the pelvis of crouch_high is 0.80 m, of crouch_medium 0.66 m
    high, medium = (r("crouch-0", state(goal_qpos(p))) for p in ("crouch_high", "crouch_medium"))
    assert high == 0.0 and medium > 0.5
    assert r("sitonground", state(goal_qpos("kneel_both"))) > 0.9
    assert r("sitonground", state(goal_qpos("sit_on_ground"))) > 0.75  # torso leans forward 50 deg
    assert r("sitonground", state(STAND)) < 0.01
    wide = state(goal_qpos("kneel_left"))  # ankles 0.78 m apart, pelvis at 0.58 m
    assert r("split-0.5", wide) > r("split-1", wide) > r("split-0.5", state(STAND)) + 0.3


def test_sitonground_asks_the_head_up():
    seat = state(goal_qpos("sit_straddle"))  # head 0.69 m
    assert r("sitonground", seat) > 0.95
    head_z = BODY_POS.start + 3 * (BODY_NAMES.index("Head") - 1) + 2
    curled = np.repeat(seat[None], 3, 0)  # the same seat with the head lowered: a body curled over its knees
    curled[:, head_z] -= [0.11, 0.16, 0.26]  # head at 0.58, 0.53 and 0.43 m
    values = get_reward("sitonground")(curled)
    assert values[0] > 0.95 and 0.4 < values[1] < 0.6 and values[2] == 0.0, values


def test_jump_pays_the_upward_speed_not_any_rise():
    up = STAND.copy()
    up[2] += 0.5  # head 2.07 m
    rising = np.stack([state(up, lin=(0, 0, v)) for v in (0.5, 1.0, 2.0, 3.0, 5.0)])
    values = get_reward("jump-2")(rising)
    assert np.all(np.diff(values) > 0) and values[-1] > 0.95, values  # a faster take-off always pays more
    assert values[0] < 0.15 < 0.35 < values[2] < 0.45, values  # a bob at 0.5 m/s: a tenth; a take-off at 2: 0.4
    bob = state(STAND, lin=(0, 0, 0.5))  # head 1.57 m, rising as a body bobbing on its knees does
    assert r("jump-2", bob) < 0.1 * r("jump-2", rising[-1])


def test_jump_rotation_handstand_crawl():
    up = STAND.copy()
    up[2] += 0.5
    assert r("jump-2", state(up, lin=(0, 0, 5))) > 0.95
    assert r("jump-2", state(up, lin=(0, 0, -2))) < 0.01 and r("jump-2", state(STAND)) < 0.01
    spin = state(STAND, ang=(0, 0, 5))
    assert r("rotate-z-5-0.8", spin) > 0.95 and r("rotate-z--5-0.8", spin) < 0.01 and r("rotate-x-5-0.8", spin) < 0.2
    cartwheel = state(STAND, ang=(-5, 0, 0))
    assert r("rotate-x--5-0.8", cartwheel) > 0.95 and r("rotate-x-5-0.8", cartwheel) < 0.01
    upside_down = pose_qpos(GoalPose(ARMS_DOWN, pitch=180))
    assert r("handstand", state(upside_down)) > 0.9 and r("handstand", state(STAND)) < 0.01
    fours = pose_qpos(GoalPose(_merge(ARMS_FORWARD, {"L_Hip_y": -90, "R_Hip_y": -90, "L_Knee_y": 90, "R_Knee_y": 90}),
                               pitch=85))  # head towards +x, belly down, spine at 0.63 m
    assert r("crawl-0.5-2-d", state(fours, lin=(2, 0, 0))) > 0.85
    assert r("crawl-0.5-2-d", state(fours, lin=(-2, 0, 0))) < 0.01  # feet first
    assert r("crawl-0.5-0-d", state(fours)) > 0.85 and r("crawl-0.5-0-u", state(fours)) < 0.01


def test_composition_product_mean_and_table_25_names():
    rng = np.random.default_rng(1)
    obs = np.stack([state(goal_qpos(g), lin=rng.normal(size=3)) for g in ("a_pose", "arms_stretch", "t_pose")])
    a, b, c = (get_reward(n)(obs) for n in ("move-ego-0-2", "raisearms-h-h", "jump-2"))
    np.testing.assert_allclose(get_reward("move-ego-0-2*raisearms-h-h")(obs), a * b, rtol=1e-5, atol=1e-7)
    b_free = RaiseArms("h", "h", calm=False)(obs)
    np.testing.assert_allclose(get_reward("move-ego-0-2-raisearms-h-h")(obs), a * b_free, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(get_reward("move-ego-0-2+jump-2")(obs), (a + c) / 2, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(get_reward("move-ego-0-2*raisearms-h-h+jump-2")(obs), (a * b + c) / 2,
                               rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(get_reward("smpl_jump-2")(obs), c)
    walk_arms_up = state(goal_qpos("arms_stretch"), lin=(2, 0, 0))
    assert r("move-ego-0-2-raisearms-h-h", walk_arms_up) > 0.95  # Table 25: no movement penalty on the arms
    assert 0.45 < r("move-ego-0-2*raisearms-h-h", walk_arms_up) < 0.55  # plain product: penalty halves it
    assert r("move-ego-0-2-raisearms-l-l", walk_arms_up) < 0.01


@pytest.mark.parametrize("bad", ["", "walk", "move-ego-0", "move-ego-a-2", "jump-", "jump-x", "raisearms-q-l",
                                 "rotate-w-5-0.8", "crawl-0.4-2-x", "a**b", "jump-2*", "+jump-2", "lieonground-left"])
def test_bad_names_raise_listing_the_families(bad):
    with pytest.raises(ValueError) as err:
        get_reward(bad)
    msg = str(err.value)
    assert all(fam in msg for fam in list_families())
    assert re.search(r"move-ego-\{angle\}-\{speed\}", msg)


def test_bad_observations_raise():
    fn = get_reward("move-ego-0-0")
    with pytest.raises(ValueError, match="358"):
        fn(np.zeros((4, 357), np.float32))
    bad = np.zeros((3, OBS_DIM), np.float32)
    bad[1, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fn(bad)
    assert fn(np.zeros((2, 3, OBS_DIM), np.float32)).shape == (2, 3)
    assert fn(state(STAND)).shape == ()
