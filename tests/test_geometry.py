"""humanoid_env.geometry: the body's lowest point, checked against MuJoCo's own geom-to-floor distance."""
import mujoco
import numpy as np
import pytest

from humanoid_env.geometry import geom_bottoms, lowest_point
from humanoid_env.inits import random_quaternions
from humanoid_env.model import default_qpos, joint_ranges, load_model

MODEL = load_model()
FLOOR = int(np.flatnonzero(MODEL.geom_bodyid == 0)[0])


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    r = joint_ranges(MODEL)
    qpos = np.tile(default_qpos(MODEL), (n, 1))
    qpos[:, :3] = rng.uniform([-1.0, -1.0, 0.5], [1.0, 1.0, 2.0], (n, 3))
    qpos[:, 3:7] = random_quaternions(rng, n)
    qpos[:, 7:] = rng.uniform(r[:, 0], r[:, 1], (n, MODEL.nq - 7))
    return qpos


def _floor_distances(qpos: np.ndarray) -> np.ndarray:
    """(ngeom,) signed distance of every geom to the floor plane by MuJoCo's collision code (floor: +inf)."""
    data = mujoco.MjData(MODEL)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(MODEL, data)
    fromto = np.zeros(6)
    out = np.full(MODEL.ngeom, np.inf)
    for g in np.flatnonzero(MODEL.geom_bodyid > 0):
        out[g] = mujoco.mj_geomDistance(MODEL, data, FLOOR, g, 10.0, fromto)
    return out


def test_standing_t_pose_touches_the_floor_and_follows_root_height():
    q = default_qpos(MODEL)
    assert abs(lowest_point(MODEL, q)) < 1e-6  # the soles are at z = 0
    lifted = np.tile(q, (4, 1))
    lifted[:, 2] += np.array([-0.3, 0.0, 0.25, 1.5])
    np.testing.assert_allclose(lowest_point(MODEL, lifted) - lowest_point(MODEL, q), [-0.3, 0.0, 0.25, 1.5],
                               atol=1e-12)


def test_rotated_poses_match_mujoco_geom_floor_distance():
    qpos = _random_poses(6, seed=0)
    bottoms = geom_bottoms(MODEL, qpos)
    expected = np.stack([_floor_distances(q) for q in qpos])
    assert np.isinf(bottoms[:, FLOOR]).all()
    np.testing.assert_allclose(bottoms, expected, atol=1e-9)
    np.testing.assert_allclose(lowest_point(MODEL, qpos), expected.min(axis=1), atol=1e-9)


def test_batch_shapes_and_bad_input():
    qpos = _random_poses(6, seed=1)
    per_pose = np.array([lowest_point(MODEL, q) for q in qpos])
    assert np.ndim(lowest_point(MODEL, qpos[0])) == 0
    np.testing.assert_array_equal(lowest_point(MODEL, qpos.reshape(2, 3, -1)), per_pose.reshape(2, 3))
    assert geom_bottoms(MODEL, qpos.reshape(3, 2, -1)).shape == (3, 2, MODEL.ngeom)
    with pytest.raises(ValueError, match="nq=76"):
        lowest_point(MODEL, qpos[:, :70])
