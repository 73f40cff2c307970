"""Named quantities read straight off batches of observation vectors, shared by all reward families.

Rewards must relabel 100k-sample buffers in well under a second, so nothing here re-runs MuJoCo kinematics:
every feature is a column slice or a small matmul over `humanoid_env.observation` layout.
"""
from __future__ import annotations

from functools import cached_property, lru_cache

import numpy as np

from humanoid_env.model import BODY_NAMES, load_model
from humanoid_env.observation import BODY_ANGVEL, BODY_LINVEL, BODY_POS, BODY_ROT, OBS_DIM

_BODY = {name: i for i, name in enumerate(BODY_NAMES)}


@lru_cache(maxsize=1)
def body_mass_weights() -> np.ndarray:
    """(24,) body masses divided by the total mass, for centre-of-mass velocities."""
    mass = np.asarray(load_model().body_mass[1:], dtype=np.float64)
    return (mass / mass.sum()).astype(np.float32)


@lru_cache(maxsize=1)
def _com_matrix() -> np.ndarray:
    """(72, 3) map from the stacked body velocities to their mass-weighted mean (one BLAS call)."""
    return np.kron(body_mass_weights()[:, None], np.eye(3, dtype=np.float32))


def as_obs_batch(obs: np.ndarray, who: str = "reward") -> np.ndarray:
    """Validate (..., 358) observations and flatten them to (N, 358)."""
    arr = np.asarray(obs)
    if arr.ndim == 0 or arr.shape[-1] != OBS_DIM:
        raise ValueError(f"{who}: expected observations of shape (..., {OBS_DIM}), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{who}: observations must be floating point, got dtype {arr.dtype}")
    flat = arr.reshape(-1, OBS_DIM)
    if not np.isfinite(flat).all():
        raise ValueError(f"{who}: observations contain NaN or inf")
    return flat


class Features:
    """Lazily computed, cached body quantities of a (N, 358) observation batch (heading frame, z up)."""

    def __init__(self, obs: np.ndarray) -> None:
        self.obs = obs

    @cached_property
    def root_z(self) -> np.ndarray:
        return self.obs[:, 0]

    def rel(self, body: str) -> np.ndarray:
        """(N, 3) position of a non-root body relative to the root, heading frame."""
        b = _BODY[body]
        if b == 0:
            return np.zeros((self.obs.shape[0], 3), dtype=self.obs.dtype)
        start = BODY_POS.start + 3 * (b - 1)
        return self.obs[:, start:start + 3]

    def z(self, body: str) -> np.ndarray:
        """(N,) world height of a body's origin."""
        return self.root_z if body == "Pelvis" else self.root_z + self.rel(body)[:, 2]

    def axis_x(self, body: str) -> np.ndarray:
        """(N, 3) the body's forward (x) axis in the heading frame."""
        start = BODY_ROT.start + 6 * _BODY[body]
        return self.obs[:, start:start + 3]

    def axis_z(self, body: str) -> np.ndarray:
        """(N, 3) the body's up (z) axis in the heading frame."""
        start = BODY_ROT.start + 6 * _BODY[body] + 3
        return self.obs[:, start:start + 3]

    def linvel(self, body: str) -> np.ndarray:
        start = BODY_LINVEL.start + 3 * _BODY[body]
        return self.obs[:, start:start + 3]

    def angvel(self, body: str) -> np.ndarray:
        start = BODY_ANGVEL.start + 3 * _BODY[body]
        return self.obs[:, start:start + 3]

    def local_angvel(self, body: str) -> np.ndarray:
        """(N, 3) angular velocity in the body's own frame (stable through flips, unlike the heading frame)."""
        x, zax = self.axis_x(body), self.axis_z(body)
        y = np.cross(zax, x)
        w = self.angvel(body)
        return np.stack([(x * w).sum(1), (y * w).sum(1), (zax * w).sum(1)], axis=1)

    @cached_property
    def com_vel(self) -> np.ndarray:
        """(N, 3) mass-weighted mean of the body-origin velocities: the centre-of-mass velocity up to small
        rotational terms, in the heading frame."""
        return self.obs[:, BODY_LINVEL] @ _com_matrix().astype(self.obs.dtype, copy=False)

    @cached_property
    def com_speed_xy(self) -> np.ndarray:
        return np.hypot(self.com_vel[:, 0], self.com_vel[:, 1])
