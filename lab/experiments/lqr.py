"""Feedback around a demonstration: time-varying LQR gains along it, and a library of such laws that picks one by
the nearest state (a funnel library, as LQR-trees build).

Why: the sampling planner rises from the floor, but its actions are a search's pick, and a policy cloned from them,
or from its labels on the policy's own states, never rose (lab/log.md sections 33-36): the labels disagree
with themselves. A linear feedback law around one planned rise is a fixed function of the state, costs a matrix
product per label, and is what keeps the rise when the state is a little off the demonstration.

The dynamics are the env's own: one control step (`N_SUBSTEPS` MuJoCo steps at a held PD target) linearised by
MuJoCo's finite differences (`mjd_transitionFD`) in its tangent space (2 x 75 values: positions, then
velocities), with the action mapping's slope on the action side. The gains come from the Riccati recursion of a
quadratic cost on the state's error and on the action's change from the demonstration's, with the rest stand's
infinite-horizon cost-to-go at the end. Errors are taken after turning the state about the vertical onto the
reference's heading and moving it onto its x, y: a rise does not depend on where the body lies or which way.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import mujoco
import numpy as np
import scipy.linalg
from scipy.spatial.transform import Rotation

from humanoid_env.env import HumanoidEnv, check_state
from humanoid_env.errors import EnvError
from humanoid_env.model import N_SUBSTEPS, NQ, NU, NV, default_qpos, load_model

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: Tangent-space state size: position errors (75, the free joint's as 3 + 3), then velocity errors (75).
STATE_DIM = 2 * NV
#: Control steps of the zero action from the default standing start before the body counts as settled.
SETTLE_STEPS = 90
#: Longest trajectory (control steps, 100 s) and most trajectories a library reads: a trajectory's gains take
#: 41 kB a step, so these bound a library's memory to what a machine has.
MAX_STEPS = 3000
MAX_TRAJECTORIES = 200


@dataclass(frozen=True)
class LqrCost:
    """Weights of the quadratic cost per control step; x, y of the root cost nothing (the heading-free error)."""

    w_height: float = 10.0    # root height error (m^2)
    w_rotation: float = 10.0  # root rotation error (rad^2, tangent space)
    w_joint: float = 1.0      # each joint angle's error (rad^2)
    w_velocity: float = 0.01  # each velocity's error
    w_action: float = 1.0     # each action component's change from the demonstration's (action units^2)

    def __post_init__(self) -> None:
        values = (self.w_height, self.w_rotation, self.w_joint, self.w_velocity, self.w_action)
        if not all(np.isfinite(v) and v >= 0 for v in values) or self.w_action <= 0:
            raise EnvError(f"LQR cost weights must be finite and >= 0, w_action > 0, got {values}")

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(Q (150, 150), R (69, 69))."""
        q = np.concatenate([[0.0, 0.0, self.w_height], np.full(3, self.w_rotation), np.full(NU, self.w_joint),
                            np.full(NV, self.w_velocity)])
        return np.diag(q), self.w_action * np.eye(NU)


def full_state(env: HumanoidEnv) -> np.ndarray:
    """The env's whole physics state, which `mj_setState` restores exactly (warm start included)."""
    state = np.empty(mujoco.mj_stateSize(env.model, _FULL))
    mujoco.mj_getState(env.model, env.data, state, _FULL)
    return state


def step_jacobians(env: HumanoidEnv, state: np.ndarray, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A (150, 150), B (150, 69)): how one control step from the physics `state` under `action` moves the
    tangent-space state, per unit of state and of action. The env is left at the step's end."""
    m, d = env.model, env.data
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    mujoco.mj_setState(m, d, state, _FULL)
    d.ctrl[:] = env.action_map.to_ctrl(a)
    a_sub, b_sub = np.zeros((STATE_DIM, STATE_DIM)), np.zeros((STATE_DIM, NU))
    A, B = np.eye(STATE_DIM), np.zeros((STATE_DIM, NU))
    for _ in range(N_SUBSTEPS):
        mujoco.mjd_transitionFD(m, d, 1e-6, 0, a_sub, b_sub, None, None)
        A, B = a_sub @ A, a_sub @ B + b_sub
        mujoco.mj_step(m, d)
    return A, B * np.where(a >= 0, env.action_map.up, env.action_map.down)[None]


def rest_stand(env: HumanoidEnv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos, qvel, physics state) of the body settled under the zero action (the rest pose's PD targets)."""
    env.reset(options={"qpos": default_qpos(), "qvel": np.zeros(NV)})
    for _ in range(SETTLE_STEPS):
        env.step(np.zeros(NU))
    return env.data.qpos.copy(), env.data.qvel.copy(), full_state(env)


def stand_cost_to_go(env: HumanoidEnv, cost: LqrCost) -> np.ndarray:
    """P (150, 150) of the infinite-horizon LQR around the rest stand: the end cost of every rise, so that the
    gains near a demonstration's end steer toward a state the stand holds."""
    _, _, state = rest_stand(env)
    A, B = step_jacobians(env, state, np.zeros(NU))
    Q, R = cost.matrices()
    return scipy.linalg.solve_discrete_are(A, B, Q + 1e-6 * np.eye(STATE_DIM), R)


def riccati_gains(jacobians: Iterable[tuple[np.ndarray, np.ndarray]], cost: LqrCost,
                  final: np.ndarray) -> np.ndarray:
    """(T, 69, 150) gains K_t of the time-varying LQR (action = demonstration's + K_t @ error) for the
    per-step (A_t, B_t), by the backward Riccati recursion from the end cost `final`."""
    Q, R = cost.matrices()
    P = final
    pairs = list(jacobians)
    K = np.zeros((len(pairs), NU, STATE_DIM))
    for t in reversed(range(len(pairs))):
        A, B = pairs[t]
        K[t] = -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A + B @ K[t])
        P = 0.5 * (P + P.T)
    return K


def align_heading(qpos: np.ndarray, qvel: np.ndarray, ref_qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The state turned about the vertical by the twist of its rotation relative to the reference's, and moved
    onto the reference's x, y: the same body, lying where and as the reference lies. The twist stays defined for
    a body on its back or front, where the pelvis's own heading is not."""
    inv, rel, turned = np.zeros(4), np.zeros(4), np.zeros(4)
    mujoco.mju_negQuat(inv, qpos[3:7])
    mujoco.mju_mulQuat(rel, ref_qpos[3:7], inv)
    psi = 2.0 * np.arctan2(rel[3], rel[0])
    mujoco.mju_mulQuat(turned, np.array([np.cos(psi / 2), 0.0, 0.0, np.sin(psi / 2)]), qpos[3:7])
    q, v = qpos.copy(), qvel.copy()
    q[0:2], q[3:7] = ref_qpos[0:2], turned
    c, s = np.cos(psi), np.sin(psi)
    v[0:2] = c * qvel[0] - s * qvel[1], s * qvel[0] + c * qvel[1]
    return q, v


def state_error(model: mujoco.MjModel, qpos: np.ndarray, qvel: np.ndarray, ref_qpos: np.ndarray,
                ref_qvel: np.ndarray) -> np.ndarray:
    """(150,) tangent-space error of the (heading-aligned) state against the reference state."""
    q, v = align_heading(qpos, qvel, ref_qpos)
    dq = np.zeros(NV)
    mujoco.mj_differentiatePos(model, dq, 1.0, ref_qpos, q)
    return np.concatenate([dq, v - ref_qvel])


@dataclass
class StabilisedTrajectory:
    """A demonstration with the feedback around it: T + 1 states, T actions, T gains, and at which of its states
    a stand policy takes over (`handoff`, see `FunnelLibrary`; None until measured)."""

    qpos: np.ndarray     # (T+1, 76)
    qvel: np.ndarray     # (T+1, 75)
    actions: np.ndarray  # (T, 69)
    gains: np.ndarray    # (T, 69, 150)
    handoff: np.ndarray | None = None  # (T,) bool

    def __post_init__(self) -> None:
        T = len(self.actions)
        if T > MAX_STEPS:
            raise EnvError(f"stabilised trajectory has {T} steps, over the limit of {MAX_STEPS}")
        shapes = {"qpos": (T + 1, NQ), "qvel": (T + 1, NV), "actions": (T, NU), "gains": (T, NU, STATE_DIM)}
        if self.handoff is not None:
            self.handoff = np.asarray(self.handoff, dtype=bool)
            shapes["handoff"] = (T,)
        for name, shape in shapes.items():
            value = getattr(self, name)
            if value.shape != shape or T < 1:
                raise EnvError(f"stabilised trajectory {name} must have shape {shape} (T >= 1), got {value.shape}")
            if not np.isfinite(value).all():
                raise EnvError(f"stabilised trajectory {name} contains NaN or inf")

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        extra = {} if self.handoff is None else {"handoff": self.handoff}
        np.savez(path, qpos=self.qpos, qvel=self.qvel, actions=self.actions, gains=self.gains.astype(np.float32),
                 **extra)
        return path

    @classmethod
    def load(cls, path: str | Path) -> StabilisedTrajectory:
        """Read one saved by `save`; a missing or malformed file is an EnvError naming it."""
        try:
            with np.load(path, allow_pickle=False) as f:
                steps = len(f["actions"])  # read first, so that an oversized file's gains are never loaded
                if steps <= MAX_STEPS:
                    arrays = {k: np.asarray(f[k], dtype=np.float64) for k in ("qpos", "qvel", "actions")}
                    arrays["gains"] = np.asarray(f["gains"], dtype=np.float32)
                    if "handoff" in f.files:
                        arrays["handoff"] = np.asarray(f["handoff"])
        except (OSError, KeyError, ValueError, TypeError) as err:
            raise EnvError(f"{path}: not a stabilised trajectory ({err})") from None
        if steps > MAX_STEPS:
            raise EnvError(f"{path}: {steps} steps, over the limit of {MAX_STEPS}")
        try:
            return cls(**arrays)
        except EnvError as err:
            raise EnvError(f"{path}: {err}") from None


def stabilise(qpos: np.ndarray, qvel: np.ndarray, actions: np.ndarray, cost: LqrCost = LqrCost(),
              progress: Callable[[int], None] | None = None) -> StabilisedTrajectory:
    """The actions replayed from the state (qpos, qvel) in a fresh env, linearised along what the env did, and
    the gains around it; `progress(t)` after each step's linearisation (it costs ~0.3 s a step)."""
    qpos, qvel = check_state(qpos, qvel)
    acts = np.asarray(actions, dtype=np.float64)
    if acts.ndim != 2 or acts.shape[1] != NU or not 1 <= len(acts) <= MAX_STEPS or not np.isfinite(acts).all():
        raise EnvError(f"actions must be finite values of shape (T, {NU}) with 1 <= T <= {MAX_STEPS}, "
                       f"got {acts.shape}")
    env = HumanoidEnv(max_episode_steps=10**9)
    final = stand_cost_to_go(env, cost)
    env.reset(options={"qpos": qpos, "qvel": qvel})
    states, qs, vs = [], [env.data.qpos.copy()], [env.data.qvel.copy()]
    for a in acts:
        states.append(full_state(env))
        env.step(a)
        qs.append(env.data.qpos.copy())
        vs.append(env.data.qvel.copy())

    def linearised():
        for t, (s, a) in enumerate(zip(states, acts)):
            yield step_jacobians(env, s, a)
            if progress is not None:
                progress(t)

    gains = riccati_gains(linearised(), cost, final)
    return StabilisedTrajectory(np.array(qs), np.array(vs), np.clip(acts, -1.0, 1.0), gains)


def match_features(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
    """(..., 151) where a state is, independent of heading and place, scaled like the cost: root height, the
    vertical in the pelvis's frame, joint angles, the root's velocities in its own frame and joint speeds."""
    lead = qpos.shape[:-1]
    world_to_body = Rotation.from_quat(qpos[..., 3:7].reshape(-1, 4), scalar_first=True).inv()
    vertical = world_to_body.apply([0.0, 0.0, 1.0]).reshape(*lead, 3)
    lin = world_to_body.apply(qvel[..., 0:3].reshape(-1, 3)).reshape(*lead, 3)
    return np.concatenate([np.sqrt(10.0) * qpos[..., 2:3], np.sqrt(10.0) * vertical, qpos[..., 7:],
                           0.1 * lin, 0.1 * qvel[..., 3:]], -1)


#: Pelvis height (m) below which a body the stand policy holds goes back to the library (lab/log.md section 38:
#: 0.5 and 0.7 did equally well).
HOLD_RELEASE = 0.7


class FunnelLibrary:
    """Stabilised trajectories acting as one state-feedback law: at each step the library state nearest the
    current one (`match_features`) picks the trajectory and step whose gains act. At states marked `handoff` (by
    default a trajectory's last `tail` steps) the rise is over, and the caller's stand policy takes over."""

    def __init__(self, trajectories: list[StabilisedTrajectory], tail: int = 5) -> None:
        if not trajectories:
            raise EnvError("a funnel library needs at least one stabilised trajectory")
        self.trajectories = trajectories
        self._model = load_model()
        T = [len(tr.actions) for tr in trajectories]
        self._features = np.concatenate([match_features(tr.qpos[:-1], tr.qvel[:-1]) for tr in trajectories])
        self._which = np.concatenate([np.full(t, j) for j, t in enumerate(T)])
        self._step = np.concatenate([np.arange(t) for t in T])
        self.handoff = np.concatenate([tr.handoff if tr.handoff is not None else np.arange(t) >= t - tail
                                       for tr, t in zip(trajectories, T)])

    @classmethod
    def load(cls, folder: str | Path, tail: int = 5) -> FunnelLibrary:
        """Every stabilised trajectory (*.npz) of a folder, in name order."""
        paths = sorted(Path(folder).glob("*.npz"))
        if not paths:
            raise EnvError(f"{folder}: no stabilised trajectories (*.npz)")
        if len(paths) > MAX_TRAJECTORIES:
            raise EnvError(f"{folder}: {len(paths)} trajectories, over the limit of {MAX_TRAJECTORIES}")
        return cls([StabilisedTrajectory.load(p) for p in paths], tail)

    def nearest(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """(N,) indices of the library states nearest the states qpos (N, 76), qvel (N, 75)."""
        qpos, qvel = np.asarray(qpos, dtype=np.float64), np.asarray(qvel, dtype=np.float64)
        if (qpos.ndim != 2 or qpos.shape[1] != NQ or qvel.shape != (len(qpos), NV)
                or not (np.isfinite(qpos).all() and np.isfinite(qvel).all())):
            raise EnvError(f"funnel library states must be finite qpos (N, {NQ}) and qvel (N, {NV}), got "
                           f"{qpos.shape} and {qvel.shape}")
        f = match_features(qpos, qvel)
        d2 = (f * f).sum(-1)[:, None] - 2 * f @ self._features.T + (self._features ** 2).sum(-1)[None]
        return np.argmin(d2, axis=1)

    def act(self, qpos: np.ndarray, qvel: np.ndarray, held: np.ndarray | None = None,
            release: float = HOLD_RELEASE) -> tuple[np.ndarray, np.ndarray]:
        """(actions (N, 69) in [-1, 1], handed (N,) bool) for the states qpos (N, 76), qvel (N, 75): where
        `handed`, the nearest state is a handoff state (or the body is held, below) and the action row is the rest
        pose's (0), for the caller to replace with its stand policy's. Pass the last step's `handed` as `held` to
        let the stand policy keep the bodies it has while their pelvis stays above `release` m: switching a
        standing body back to some trajectory's gains by its nearest state loses most of the bodies that fail
        (lab/log.md section 38)."""
        k = self.nearest(qpos, qvel)
        handed = self.handoff[k]
        if held is not None:
            held = np.asarray(held, dtype=bool)
            if held.shape != handed.shape:
                raise EnvError(f"funnel library: held must be ({len(handed)},) bool, got shape {held.shape}")
            if not np.isfinite(release):
                raise EnvError(f"funnel library: release must be a finite pelvis height, got {release}")
            handed = handed | (held & (np.asarray(qpos)[:, 2] > release))
        actions = np.zeros((len(k), NU))
        for i in np.flatnonzero(~handed):  # one MuJoCo call per state for the tangent-space error
            tr, t = self.trajectories[self._which[k[i]]], self._step[k[i]]
            error = state_error(self._model, qpos[i], qvel[i], tr.qpos[t], tr.qvel[t])
            actions[i] = np.clip(tr.actions[t] + tr.gains[t] @ error, -1.0, 1.0)
        return actions, handed
