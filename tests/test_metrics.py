"""Metrics of App. C.3 on small synthetic trajectories whose values are worked out by hand."""
import warnings

import numpy as np
import pytest

from fbcpr.metrics import d_smpl, emd, goal_proximity, goal_success, pose_part, tracking_success


def traj(values, dim=0):
    """(T, 358) trajectory whose pose coordinate `dim` follows `values`; velocities are noise (ignored)."""
    out = np.random.default_rng(len(values)).normal(size=(len(values), 358))
    out[:, :214] = 0.0
    out[:, dim] = values
    return out


def test_d_smpl_uses_only_the_pose_part():
    a, b = np.zeros(358), np.zeros(358)
    b[214:] = 7.0  # velocities differ: no distance
    assert d_smpl(a, b) == 0.0
    b[3], b[200] = 3.0, 4.0
    assert d_smpl(a, b) == pytest.approx(5.0)
    assert d_smpl(a[:214], b) == pytest.approx(5.0)  # pose vectors work too
    np.testing.assert_allclose(d_smpl(np.zeros((2, 3, 358)), b), np.full((2, 3), 5.0))


def test_goal_success_and_proximity_by_hand():
    d = np.array([[5.0, 3.0, 2.5, 1.0], [6.0, 4.0, 4.5, 2.1]])
    np.testing.assert_array_equal(goal_success(d), [1.0, 0.0])
    # per step: d<=2 -> 1; 2<d<=4 -> (4-d)/2; d>4 -> 0
    np.testing.assert_allclose(goal_proximity(d), [(0 + 0.5 + 0.75 + 1) / 4, (0 + 0 + 0 + 0.95) / 4])
    assert goal_success(np.array([2.0])) == 1.0 and goal_proximity(np.array([2.0])) == 1.0


def test_tracking_success_by_hand():
    ref = traj([0.0, 1.0, 2.0, 3.0])
    assert tracking_success(traj([0.0, 1.4, 2.5, 3.0]), ref)
    assert not tracking_success(traj([0.0, 1.6, 2.0, 3.0]), ref)  # one step at 0.6 > 0.5
    with pytest.raises(ValueError, match="equal shape"):
        tracking_success(traj([0.0, 1.0]), ref)


def test_emd_by_hand():
    ref = traj([0.0, 1.0, 2.0])
    assert emd(traj([2.0, 0.0, 1.0]), ref) == pytest.approx(0.0, abs=1e-12)  # time order does not matter
    assert emd(traj([0.0, 1.0, 2.0]) + np.eye(358)[5] * 2, ref) == pytest.approx(2.0)  # constant 2 offset
    assert emd(traj([1.0, 2.0, 3.0]), ref) == pytest.approx(1.0)  # total transport 3, mass 1/3 each
    assert emd(traj([1.0]), traj([0.0, 2.0])) == pytest.approx(1.0)  # unequal lengths: uniform weights


def test_emd_of_long_trajectories_reaches_the_optimum():
    ot = pytest.importorskip("ot")
    rng = np.random.default_rng(0)
    n = 1400  # a long clip: POT's default iteration cap stops short here, with a warning
    pad = ((0, 0), (0, 214 - 20))  # 20 moving pose features
    clip = np.pad(np.sin(np.linspace(0, 20, n)[:, None] * rng.uniform(0.5, 2, (1, 20))), pad)
    fallen = np.pad(rng.normal(size=(1, 20)) + rng.normal(0, 1e-3, (n, 20)), pad)  # an agent lying still
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exact = emd(clip, fallen)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        w = np.full(n, 1.0 / n)
        capped = ot.emd2(w, w, ot.dist(clip, fallen, metric="euclidean"))
    assert caught and exact < capped  # the capped solve warned and is a worse (higher) transport cost


def test_metric_inputs_are_checked():
    with pytest.raises(ValueError, match="358"):
        d_smpl(np.zeros(10), np.zeros(10))
    bad = np.zeros((3, 358))
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        emd(bad, np.zeros((3, 358)))
    with pytest.raises(ValueError, match="non-empty"):
        emd(np.zeros((0, 358)), np.zeros((3, 358)))
    assert pose_part(np.ones((2, 358))).shape == (2, 214)


def test_dtw_pose_error_forgives_time_warps_but_not_offsets():
    from fbcpr.metrics import dtw_pose_error

    t = np.linspace(0, 2 * np.pi, 50)
    path = np.stack([np.cos(t), np.sin(t), 0.1 * t], 1)
    slow = np.repeat(path, 3, axis=0)                      # the same motion at a third of the speed
    assert dtw_pose_error(slow, path) == pytest.approx(0.0, abs=1e-12)
    assert dtw_pose_error(path + [0.0, 0.0, 0.3], path) == pytest.approx(0.3)
    # time-aligned, a phase lag costs; the warp takes most of it back
    lagged = np.roll(path, 5, axis=0)
    assert dtw_pose_error(lagged, path) < np.linalg.norm(lagged - path, axis=1).mean()
    with pytest.raises(ValueError, match="dtw_pose_error"):
        dtw_pose_error(path[:, :2], path)
    with pytest.raises(ValueError, match="NaN"):
        dtw_pose_error(np.full_like(path, np.nan), path)


def test_sparc_ranks_smooth_above_jerky_and_ignores_duration():
    from fbcpr.metrics import sparc, speed_profile

    fps = 30.0

    def bell(seconds):
        t = np.arange(0, seconds, 1 / fps)
        return np.exp(-0.5 * ((t - seconds / 2) / (seconds / 8)) ** 2)

    smooth = bell(2.0)
    jerky = smooth * (1 + 0.5 * np.sin(2 * np.pi * 4 * np.arange(len(smooth)) / fps))   # 4 Hz tremor
    assert sparc(jerky, fps) < sparc(smooth, fps) < -1.0
    assert sparc(bell(4.0), fps) == pytest.approx(sparc(bell(2.0), fps), abs=0.05)       # time-scale invariant
    assert sparc(np.zeros(20), fps) == 0.0
    np.testing.assert_allclose(speed_profile(np.array([[0, 0], [3, 4], [3, 4]]), fps), [150.0, 0.0])
    with pytest.raises(ValueError, match="sparc"):
        sparc(np.array([1.0, np.nan, 2.0]), fps)
