"""How an action in [-1, 1]^69 becomes a PD target: one place for both mappings the env offers.

- ``rest`` (default): piecewise linear, [-1, 0] -> [low, rest] and [0, 1] -> [rest, high], with rest = 0 rad
  (the standing rest pose). Action 0 holds the humanoid up (it stands the full 10 s), and every joint's full
  range stays reachable, so a fresh actor, which outputs about 0, starts its exploration from standing.
- ``mid``: linear over the range, action 0 = the middle of each joint's range (a deep crouch that falls in
  0.8 s). The mapping of HumEnv, and of every checkpoint this package wrote before ``rest`` existed.

Observations, rewards, clips and goal poses are defined on joint angles and bodies, never on actions, so the
choice changes only what the policy's output means.
"""
from __future__ import annotations

import mujoco
import numpy as np

from humanoid_env.errors import InvalidActionError

ACTION_MAPPINGS = ("rest", "mid")
DEFAULT_ACTION_MAPPING = "rest"
#: The mapping of checkpoints whose config predates the option.
LEGACY_ACTION_MAPPING = "mid"


def check_action(action: object, shape: tuple[int, ...], name: str) -> np.ndarray:
    """The action as a float64 array, checked for shape and finiteness before any clipping (which would turn
    +inf into a valid 1); `name` ("action", "actions") starts every message."""
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidActionError(f"{name} must be numbers, got {type(action).__name__} "
                                 f"of {np.asarray(action).dtype}") from None
    if a.shape != shape:
        raise InvalidActionError(f"{name} must have shape {shape}, got {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        where = f" (envs {np.flatnonzero(bad.any(axis=1)).tolist()})" if a.ndim == 2 else ""
        raise InvalidActionError(f"{name} contain NaN or inf{where}" if a.ndim == 2 else f"{name} contains NaN or inf")
    return a


class ActionMap:
    """Maps actions to PD targets (``to_ctrl``) and joint angles back to actions (``from_angles``)."""

    def __init__(self, model: mujoco.MjModel, mapping: str = DEFAULT_ACTION_MAPPING) -> None:
        if mapping not in ACTION_MAPPINGS:
            raise ValueError(f"action_mapping must be one of {ACTION_MAPPINGS}, got {mapping!r}")
        self.mapping = mapping
        lo, hi = model.actuator_ctrlrange[:, 0].copy(), model.actuator_ctrlrange[:, 1].copy()
        self.center = np.clip(0.0, lo, hi) if mapping == "rest" else (lo + hi) / 2
        # scale of the positive and negative half of [-1, 1]; equal for the linear `mid` mapping
        self.up = np.maximum(hi - self.center, 1e-9)
        self.down = np.maximum(self.center - lo, 1e-9)

    def to_ctrl(self, action: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """PD targets (radians) of actions already clipped to [-1, 1]; written into `out` when given."""
        scale = np.where(action >= 0, self.up, self.down)
        out = np.multiply(action, scale, out=out)
        out += self.center
        return out

    def from_angles(self, angles: np.ndarray) -> np.ndarray:
        """The action whose PD target is `angles` (..., 69), clipped to [-1, 1]."""
        rel = np.asarray(angles, dtype=np.float64) - self.center
        return np.clip(rel / np.where(rel >= 0, self.up, self.down), -1.0, 1.0).astype(np.float32)
