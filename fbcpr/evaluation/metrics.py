"""Evaluation metrics of the FB-CPR paper (App. C.3.2 and C.3.3), one implementation each.

All distances use d_smpl: the Euclidean distance between the pose parts (observation[..., :214]: root height,
body positions and orientations; velocities ignored). Inputs may be full observations (..., 358) or pose
parts (..., 214).

POT is imported only when an EMD is computed, so training runs where it is not installed (the GPU lease
image, benchmarks/gpu_lease): there the trainer's tracking EMD falls back to an exact assignment solver.
"""
from __future__ import annotations

import numpy as np

from humanoid_env.observation import OBS_DIM, POSE

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
        raise ValueError(f"{who}: expected last dimension {OBS_DIM} (observation) or {POSE_DIM} (pose), "
                         f"got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{who}: input contains NaN or inf")
    return arr[..., POSE] if arr.shape[-1] == OBS_DIM else arr


def d_smpl(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between pose parts, broadcast over leading axes."""
    return np.linalg.norm(pose_part(a, "d_smpl") - pose_part(b, "d_smpl"), axis=-1)


def goal_success(dist: np.ndarray, beta: float = GOAL_BETA) -> np.ndarray:
    """1 where the goal was reached (d <= beta) at any step; `dist` is (..., T) over an episode."""
    return (np.asarray(dist) <= beta).any(axis=-1).astype(np.float64)


def goal_proximity(dist: np.ndarray, beta: float = GOAL_BETA, sigma: float = GOAL_SIGMA) -> np.ndarray:
    """Time average of 1 (d <= beta), (beta + sigma - d) / sigma (beta < d <= beta + sigma), 0 beyond."""
    score = np.clip((beta + sigma - np.asarray(dist, dtype=np.float64)) / sigma, 0.0, 1.0)
    return score.mean(axis=-1)


def tracking_success(agent: np.ndarray, reference: np.ndarray, xi: float = TRACK_XI) -> bool:
    """True when the agent stays within d_smpl <= xi of the reference at every step (time-aligned, equal length)."""
    a, r = pose_part(agent, "tracking_success"), pose_part(reference, "tracking_success")
    if a.ndim != 2 or a.shape != r.shape:
        raise ValueError(f"tracking_success: trajectories must be (T, D) of equal shape, got {a.shape} and {r.shape}")
    return bool((np.linalg.norm(a - r, axis=-1) <= xi).all())


def emd(agent: np.ndarray, reference: np.ndarray) -> float:
    """Earth mover's distance between two trajectories seen as uniform point clouds of pose parts,
    with d_smpl as ground cost (POT's exact solver); insensitive to small time misalignments."""
    a, r = pose_part(agent, "emd"), pose_part(reference, "emd")
    if a.ndim != 2 or r.ndim != 2 or len(a) == 0 or len(r) == 0:
        raise ValueError(f"emd: trajectories must be non-empty (T, D) arrays, got {a.shape} and {r.shape}")
    try:
        import ot
    except ModuleNotFoundError:
        return _emd_by_assignment(a, r)
    cost = ot.dist(a, r, metric="euclidean")
    return float(ot.emd2(np.full(len(a), 1.0 / len(a)), np.full(len(r), 1.0 / len(r)), cost))


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
