"""Evaluation metrics of the FB-CPR paper (App. C.3.2 and C.3.3), one implementation each.

The imitation metrics of NEAR (average DTW pose error, SPARC) follow the tracking metrics.
All distances use d_smpl: the Euclidean distance between the pose parts (observation[..., :214]: root height,
body positions and orientations; velocities ignored). Inputs may be full observations (..., 358) or pose
parts (..., 214).

POT is imported only when an EMD is computed, so training runs where it is not installed (e.g. a minimal GPU
image): there the trainer's tracking EMD falls back to an exact assignment solver.
"""
from __future__ import annotations

import numpy as np

from fbcpr.core.errors import InputError
from humanoid_env.observation import BODY_LINVEL, BODY_POS, OBS_DIM, POSE

POSE_DIM = POSE.stop - POSE.start
GOAL_BETA = 2.0      # goal reached when d_smpl <= beta
GOAL_SIGMA = 2.0     # proximity decays linearly to 0 over this margin beyond beta
TRACK_XI = 0.5       # tracking succeeds when d_smpl <= xi at every step


class EMDUnavailable(ImportError):
    """No solver for this EMD: POT is not installed and the assignment fallback does not apply."""


def pose_part(x: np.ndarray, who: str = "pose_part") -> np.ndarray:
    """The pose part of observations (..., 358) or pose vectors (..., 214), as float64."""
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] not in (OBS_DIM, POSE_DIM):
        raise InputError(f"{who}: expected last dimension {OBS_DIM} (observation) or {POSE_DIM} (pose), "
                         f"got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError(f"{who}: input contains NaN or inf")
    return arr[..., POSE] if arr.shape[-1] == OBS_DIM else arr


def d_smpl(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between pose parts, broadcast over leading axes."""
    return np.linalg.norm(pose_part(a, "d_smpl") - pose_part(b, "d_smpl"), axis=-1)


def mpjpe(agent: np.ndarray, reference: np.ndarray) -> float:
    """Mean per-joint position error in metres of two time-aligned trajectories (T, 358 or 214): the distance
    between each non-root body's position relative to the pelvis (heading frame), averaged over bodies and steps."""
    a, r = pose_part(agent, "mpjpe"), pose_part(reference, "mpjpe")
    if a.ndim != 2 or a.shape != r.shape or len(a) == 0:
        raise InputError(f"mpjpe: trajectories must be non-empty (T, D) of equal shape, got {a.shape} and {r.shape}")
    diff = (a[:, BODY_POS] - r[:, BODY_POS]).reshape(len(a), -1, 3)
    return float(np.linalg.norm(diff, axis=-1).mean())


def goal_success(dist: np.ndarray, beta: float = GOAL_BETA) -> np.ndarray | np.float64:
    """1 where the goal was reached (d <= beta) at any step; `dist` is (..., T) over an episode (a scalar for one)."""
    return (np.asarray(dist) <= beta).any(axis=-1).astype(np.float64)


def goal_proximity(dist: np.ndarray, beta: float = GOAL_BETA, sigma: float = GOAL_SIGMA) -> np.ndarray:
    """Time average of 1 (d <= beta), (beta + sigma - d) / sigma (beta < d <= beta + sigma), 0 beyond."""
    score = np.clip((beta + sigma - np.asarray(dist, dtype=np.float64)) / sigma, 0.0, 1.0)
    return score.mean(axis=-1)


def tracking_success(agent: np.ndarray, reference: np.ndarray, xi: float = TRACK_XI) -> bool:
    """True when the agent stays within d_smpl <= xi of the reference at every step (time-aligned, equal length)."""
    a, r = pose_part(agent, "tracking_success"), pose_part(reference, "tracking_success")
    if a.ndim != 2 or a.shape != r.shape:
        raise InputError(f"tracking_success: trajectories must be (T, D) of equal shape, got {a.shape} and {r.shape}")
    return bool((np.linalg.norm(a - r, axis=-1) <= xi).all())


def emd(agent: np.ndarray, reference: np.ndarray) -> float:
    """Earth mover's distance between two trajectories seen as uniform point clouds of pose parts,
    with d_smpl as ground cost (POT's exact solver); insensitive to small time misalignments."""
    a, r = pose_part(agent, "emd"), pose_part(reference, "emd")
    if a.ndim != 2 or r.ndim != 2 or len(a) == 0 or len(r) == 0:
        raise InputError(f"emd: trajectories must be non-empty (T, D) arrays, got {a.shape} and {r.shape}")
    try:
        import ot
    except ModuleNotFoundError:
        return _emd_by_assignment(a, r)
    cost = ot.dist(a, r, metric="euclidean")
    # POT's default cap of 100k simplex iterations stops short of the optimum (with a warning) on clips of ~1,400
    # frames and more; a few iterations per cost entry reach it on every clip we track
    cap = max(100_000, 4 * cost.size)
    return float(ot.emd2(np.full(len(a), 1.0 / len(a)), np.full(len(r), 1.0 / len(r)), cost, numItermax=cap))


def _emd_by_assignment(a: np.ndarray, r: np.ndarray) -> float:
    """The same EMD without POT, for equal lengths (all tracking compares): with n uniform points on each side
    an optimal transport plan is a permutation (Birkhoff), so the EMD is the mean cost of scipy's optimal
    assignment. Raises EMDUnavailable for unequal lengths or without scipy."""
    if len(a) != len(r):
        raise EMDUnavailable(f"emd: trajectories of unequal length ({len(a)} vs {len(r)}) need POT (pip install POT)")
    try:
        from scipy.optimize import linear_sum_assignment
        from scipy.spatial.distance import cdist
    except ModuleNotFoundError:
        raise EMDUnavailable("emd: needs POT or scipy (pip install POT)") from None
    cost = cdist(a, r)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].mean())


def dtw_pose_error(agent: np.ndarray, expert: np.ndarray) -> float:
    """NEAR's average DTW pose error: the mean Euclidean distance between the poses that dynamic time warping
    (dtaidistance's C implementation) pairs up along its optimal path. Inputs: (T, D) and (T', D) pose features,
    e.g. root-relative body positions; the time warp forgives phase shifts and speed differences."""
    from dtaidistance import dtw_ndim

    a, e = np.ascontiguousarray(agent, dtype=np.float64), np.ascontiguousarray(expert, dtype=np.float64)
    if a.ndim != 2 or e.ndim != 2 or a.shape[1] != e.shape[1] or not (len(a) and len(e)):
        raise InputError(f"dtw_pose_error: expected non-empty (T, D) trajectories, got {a.shape} and {e.shape}")
    if not (np.isfinite(a).all() and np.isfinite(e).all()):
        raise InputError("dtw_pose_error: input contains NaN or inf")
    path = np.asarray(dtw_ndim.warping_path(a, e, inner_dist="euclidean", use_c=True))
    return float(np.linalg.norm(a[path[:, 0]] - e[path[:, 1]], axis=-1).mean())


def speed_profile(positions: np.ndarray, fps: float) -> np.ndarray:
    """|velocity| (T-1,) of a (T, 3) (or (T, 2)) position trajectory sampled at `fps` frames per second."""
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or len(p) < 2:
        raise InputError(f"speed_profile: expected (T >= 2, D) positions, got {p.shape}")
    return np.linalg.norm(np.diff(p, axis=0), axis=-1) * fps


def sparc(speed: np.ndarray, fps: float, pad_level: int = 4, cutoff_hz: float = 10.0,
          amp_threshold: float = 0.05) -> float:
    """Spectral arc length (SPARC, Balasubramanian et al. 2015): minus the arc length of the normalised magnitude
    spectrum of a speed profile, up to the adaptive cut-off where the spectrum falls below `amp_threshold`
    (at most `cutoff_hz`). Closer to 0 is smoother; compare an agent's with its expert's."""
    v = np.asarray(speed, dtype=np.float64)
    if v.ndim != 1 or len(v) < 2 or not np.isfinite(v).all():
        raise InputError(f"sparc: expected a finite (T >= 2,) speed profile, got shape {v.shape}")
    if not v.any():
        return 0.0  # no motion: a flat spectrum of zero length
    nfft = int(2 ** (np.ceil(np.log2(len(v))) + pad_level))
    freq = np.fft.rfftfreq(nfft, 1.0 / fps)
    mag = np.abs(np.fft.rfft(v, nfft))
    mag = mag / mag.max()
    keep = freq <= cutoff_hz
    freq, mag = freq[keep], mag[keep]
    above = np.flatnonzero(mag >= amp_threshold)
    freq, mag = freq[above[0]: above[-1] + 1], mag[above[0]: above[-1] + 1]
    if len(freq) < 2:
        return 0.0
    return float(-np.sum(np.hypot(np.diff(freq) / (freq[-1] - freq[0]), np.diff(mag))))


def imitation_scores(agent: np.ndarray, reference: np.ndarray, fps: float = 30.0) -> dict[str, float]:
    """NEAR's imitation metrics of two humanoid observation trajectories (T, 358): DTW pose error over the
    root-relative body positions (the 2-norm of all 23 stacked, in metres, as NEAR), and SPARC of the root's
    speed (body 0's linear velocity) for the agent and for the reference."""
    a, r = np.asarray(agent, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    if a.ndim != 2 or r.ndim != 2 or a.shape[1] != OBS_DIM or r.shape[1] != OBS_DIM:
        raise InputError(f"imitation_scores: expected (T, {OBS_DIM}) observations, got {a.shape} and {r.shape}")
    root_speed = slice(BODY_LINVEL.start, BODY_LINVEL.start + 3)
    return {"dtw": dtw_pose_error(a[:, BODY_POS], r[:, BODY_POS]),
            "sparc": sparc(np.linalg.norm(a[:, root_speed], axis=-1), fps),
            "sparc_expert": sparc(np.linalg.norm(r[:, root_speed], axis=-1), fps)}
