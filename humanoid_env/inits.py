"""Initial-state samplers: `sample(rng, n) -> (qpos (n,76), qvel (n,75))`.

Default (standing T-pose with small noise), Fall (a random pose dropped from a height), MoCap (states of a
motion library) and mixtures of them (`make_init(fall_prob, mocap)`; the FB-CPR paper trains with
fall_prob = 0.2 on top of MoCap).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import mujoco
import numpy as np

from humanoid_env.errors import EnvError, InvalidStateError
from humanoid_env.geometry import lowest_point
from humanoid_env.model import NQ, NV, default_qpos, joint_ranges, load_model


class StateSource(Protocol):
    """A motion library: anything with `sample_states(rng, n) -> (qpos (n,76), qvel (n,75))`."""

    def sample_states(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]: ...


class Sampler(Protocol):
    """A mixture's component: anything that draws initial states, like the samplers here (the env's `InitSampler`)."""

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]: ...


class _Geometry:
    """Where a pose touches: its lowest point above the floor and its deepest self-penetration."""

    def __init__(self) -> None:
        self.model = load_model()
        self.data = mujoco.MjData(self.model)

    def lowest_z(self, qpos: np.ndarray) -> np.ndarray:
        """(n,) lowest z of the body for each pose in qpos (n,76)."""
        return lowest_point(self.model, qpos, self.data)

    def self_penetration(self, qpos: np.ndarray) -> np.ndarray:
        """(n,) deepest penetration (m, >= 0) between body geoms, floor excluded, for each pose in qpos (n,76)."""
        out = np.zeros(len(qpos))
        m, d = self.model, self.data
        for i, q in enumerate(qpos):
            d.qpos[:] = q
            d.qpos[2] = 10.0  # far above the floor: only self-contacts remain
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            if d.ncon:
                out[i] = max(0.0, -d.contact.dist[: d.ncon].min())
        return out


def random_quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n,4) uniformly distributed unit quaternions (wxyz)."""
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _check_n(n: int) -> None:
    if n < 0:
        raise EnvError(f"number of states must be >= 0, got {n}")


class DefaultInit:
    """Standing T-pose with uniform joint-angle noise (rad) and Gaussian velocity noise, feet on the floor."""

    def __init__(self, angle_noise: float = 0.02, vel_noise: float = 0.02) -> None:
        self.angle_noise, self.vel_noise = float(angle_noise), float(vel_noise)
        self._geom = _Geometry()
        self._qpos0 = default_qpos(self._geom.model)
        self._range = joint_ranges(self._geom.model)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        _check_n(n)
        qpos = np.tile(self._qpos0, (n, 1))
        qpos[:, 7:] = np.clip(
            qpos[:, 7:] + rng.uniform(-self.angle_noise, self.angle_noise, (n, NQ - 7)), self._range[:, 0],
            self._range[:, 1]
        )
        qpos[:, 2] -= np.minimum(self._geom.lowest_z(qpos), 0.0)  # lift out of the floor if the noise pushed a foot in
        qvel = rng.normal(0.0, self.vel_noise, (n, NV))
        return qpos, qvel


class FallInit:
    """Random joint angles within the ranges and a random orientation, the lowest point `height` above the floor.

    Poses whose limbs overlap by more than `max_overlap` metres are redrawn (up to `tries` times), so that the
    first step does not start from a violent self-collision.
    """

    def __init__(
        self, height: tuple[float, float] = (0.2, 1.0), vel_noise: float = 0.0, max_overlap: float = 0.01,
        tries: int = 20
    ) -> None:
        if not 0.0 <= height[0] <= height[1]:
            raise EnvError(f"height must be a range 0 <= low <= high, got {height}")
        self.height, self.vel_noise = (float(height[0]), float(height[1])), float(vel_noise)
        self.max_overlap, self.tries = float(max_overlap), int(tries)
        self._geom = _Geometry()
        self._range = joint_ranges(self._geom.model)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        _check_n(n)
        qpos = np.zeros((n, NQ))
        qpos[:, :2] = rng.uniform(-1.0, 1.0, (n, 2))
        qpos[:, 3:7] = random_quaternions(rng, n)
        redo = np.arange(n)
        for _ in range(self.tries):
            qpos[redo, 7:] = rng.uniform(self._range[:, 0], self._range[:, 1], (len(redo), NQ - 7))
            redo = redo[self._geom.self_penetration(qpos[redo]) > self.max_overlap]
            if len(redo) == 0:
                break
        drop = rng.uniform(*self.height, n)
        qpos[:, 2] = drop - self._geom.lowest_z(qpos)
        qvel = rng.normal(0.0, self.vel_noise, (n, NV)) if self.vel_noise > 0 else np.zeros((n, NV))
        return qpos, qvel


class MocapInit:
    """States of a motion library (any object with `sample_states(rng, n)`)."""

    def __init__(self, source: StateSource) -> None:
        if not callable(getattr(source, "sample_states", None)):
            raise TypeError(f"MocapInit needs an object with sample_states(rng, n), got {type(source).__name__}")
        self.source = source

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        _check_n(n)
        qpos, qvel = self.source.sample_states(rng, n)
        qpos, qvel = np.asarray(qpos, dtype=np.float64), np.asarray(qvel, dtype=np.float64)
        if qpos.shape != (n, NQ) or qvel.shape != (n, NV):
            raise InvalidStateError(f"motion library returned qpos {qpos.shape} and qvel {qvel.shape}, expected "
                                    f"({n},{NQ}) and ({n},{NV})")
        return qpos, qvel


class FixedStates:
    """Given states, in order and repeated to fill a batch (env i starts state i mod k): evaluations that start
    every env from chosen states, such as a clip's frames or demonstrations' first states."""

    def __init__(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        qpos, qvel = np.asarray(qpos, dtype=np.float64), np.asarray(qvel, dtype=np.float64)
        if qpos.ndim != 2 or len(qpos) == 0 or qpos.shape[1:] != (NQ,) or qvel.shape != (len(qpos), NV):
            raise InvalidStateError(f"FixedStates needs qpos (k, {NQ}) and qvel (k, {NV}) with k >= 1, got "
                                    f"{qpos.shape} and {qvel.shape}")
        self.qpos, self.qvel = qpos, qvel

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        _check_n(n)
        i = np.arange(n) % len(self.qpos)
        return self.qpos[i], self.qvel[i]


class MixtureInit:
    """Each state comes from component k with probability weights[k]."""

    def __init__(self, components: Sequence[Sampler], weights: Sequence[float]) -> None:
        w = np.asarray(weights, dtype=np.float64)
        if len(components) == 0 or w.shape != (len(components),) or (w < 0).any() or w.sum() <= 0:
            raise EnvError(f"MixtureInit needs one non-negative weight per component with a positive sum, got "
                           f"{list(weights)}")
        self.components, self.weights = list(components), w / w.sum()

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        _check_n(n)
        which = rng.choice(len(self.components), size=n, p=self.weights)
        qpos, qvel = np.empty((n, NQ)), np.empty((n, NV))
        for k, comp in enumerate(self.components):
            idx = np.flatnonzero(which == k)
            if len(idx):
                qpos[idx], qvel[idx] = comp.sample(rng, len(idx))
        return qpos, qvel


def make_init(fall_prob: float, mocap: StateSource | None = None, stand_prob: float = 0.0,
              focus: StateSource | None = None, focus_prob: float = 0.0) -> MixtureInit:
    """Fall with probability fall_prob, the standing rest pose with probability stand_prob, states of `focus` (a
    few chosen clips, e.g. a getup clip: starts part-way through a skill that exploration alone does not reach)
    with probability focus_prob, otherwise MoCap states (or the standing pose when no library is given). Standing
    starts are where balance is easiest to learn."""
    if not 0.0 <= fall_prob <= 1.0:
        raise EnvError(f"fall_prob must be in [0, 1], got {fall_prob}")
    if not 0.0 <= stand_prob <= 1.0 - fall_prob + 1e-9:
        raise EnvError(f"stand_prob must be in [0, 1 - fall_prob] = [0, {1.0 - fall_prob:g}], got {stand_prob}")
    if not 0.0 <= focus_prob <= 1.0 - fall_prob - stand_prob + 1e-9:
        raise EnvError(f"focus_prob must be in [0, 1 - fall_prob - stand_prob] = "
                       f"[0, {max(0.0, 1.0 - fall_prob - stand_prob):g}], got {focus_prob}")
    if focus_prob > 0 and focus is None:
        raise EnvError("focus_prob > 0 needs a focus state source")
    base = MocapInit(mocap) if mocap is not None else DefaultInit()
    parts = [base, FallInit(), DefaultInit()] + ([MocapInit(focus)] if focus is not None else [])
    weights = [max(0.0, 1.0 - fall_prob - stand_prob - focus_prob), fall_prob, stand_prob]
    return MixtureInit(parts, weights + [focus_prob] * (focus is not None))
