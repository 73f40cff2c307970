"""A sampling planner that tracks a reference motion with the env's own physics (predictive sampling, as in MuJoCo MPC).

Why: no learnt policy has got the humanoid up from the floor (lab/log.md sections 18-31), and the question
under that is whether this body, with its PD gains and torque limits, can rise at all. A planner that sees the
simulator answers it, and what it executes is a physically consistent motion with the actions that make it.

Every `execute` control steps it draws `samples` action sequences over `horizon` steps: the reference's joint
angles as PD targets (the feed-forward), plus the current correction, plus Gaussian noise on knots every
`knot_every` steps (linear in between; candidate 0 keeps the current correction without noise). All of them are
rolled out in parallel (`mujoco.rollout`, C threads) from the current state, and the mean of the `elites` cheapest
becomes the correction (with 1, the cheapest is kept). `iterations` > 1 repeats that draw around the new correction
within one plan (the cross-entropy method), with the noise shrunk by `noise_decay` each time. `chains` > 1 runs that
many such planners side by side on the same state, each keeping its own correction, and executes the mean of their
plans. The next plan starts from the share `warm_start` of the correction. Both are for labels (lab/log.md
sections 35-36): a full warm start makes one planner's choice a random walk of kept noise; the mean of four walks is
steadier but did not rise, and keeping 95% rose with labels 2.6 times less noisy. The plan's first `execute`
actions are then applied in a real `HumanoidEnv`, so the returned trajectory is exactly what the env does with
those actions. The cost, summed over the horizon: joint-angle error to the reference, pelvis height error, tilt
of the pelvis's up axis against the reference's, joint speeds, and root speed. After the reference ends the target
blends into the rest pose (action 0), which stands on its own.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Callable

import mujoco
import numpy as np
from mujoco import rollout

from humanoid_env.actions import DEFAULT_ACTION_MAPPING, check_action
from humanoid_env.env import HumanoidEnv, check_state
from humanoid_env.errors import EnvError
from humanoid_env.model import N_SUBSTEPS, NQ, NU, NV, model_path

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: A target pelvis above this is a standing one, where the balance term applies.
STANDING_TARGET = 0.8
_FEET = ("L_Ankle", "R_Ankle", "L_Toe", "R_Toe")


def sensing_model() -> mujoco.MjModel:
    """The humanoid with sensors for the planner's cost (centre of mass, its velocity, the feet); the physics is
    the env's model's, unchanged. MuJoCo reads sensors at the start of a physics step, so they lag the recorded
    state by one step (2.2 ms), which a cost summed over control steps can ignore."""
    spec = mujoco.MjSpec.from_file(model_path())
    body = mujoco.mjtObj.mjOBJ_BODY
    spec.add_sensor(type=mujoco.mjtSensor.mjSENS_SUBTREECOM, objtype=body, objname="Pelvis")
    spec.add_sensor(type=mujoco.mjtSensor.mjSENS_SUBTREELINVEL, objtype=body, objname="Pelvis")
    for name in _FEET:
        spec.add_sensor(type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=body, objname=name)
    return spec.compile()


@dataclass(frozen=True)
class PlannerConfig:
    """Sizes and cost weights of the planner (defaults: what rose from the getup clip's first frame, section 32)."""

    samples: int = 32          # candidate action sequences per plan, candidate 0 the current one
    horizon: int = 40          # control steps looked ahead (1.33 s at 30 Hz: 20 rose but fell after)
    execute: int = 2           # control steps applied from each plan
    knot_every: int = 4        # control steps between noise knots
    noise: float = 0.1         # std of the knot noise, in action units
    iterations: int = 1        # draws per plan, each around the last one's correction (cross-entropy method)
    elites: int = 1            # cheapest candidates averaged into the correction (1: the cheapest alone)
    noise_decay: float = 1.0   # the knot noise's factor from one iteration to the next
    chains: int = 1            # independent planners on the same state, each with its own correction; the mean
                               # of their plans is executed (and is the label), so a label's noise shrinks
    rate: float = 1.0          # reference frames advanced per control step
    blend_steps: int = 15      # control steps over which the target blends into the rest pose after the reference
    w_pose: float = 1.0        # mean squared joint-angle error (rad^2)
    w_height: float = 20.0     # squared pelvis height error (m^2)
    w_tilt: float = 2.0        # 1 - cos of the pelvis up axis against the reference's
    w_joint_speed: float = 1e-3
    w_root_speed: float = 0.1      # horizontal pelvis speed squared (m^2/s^2)
    w_root_spin: float = 0.01      # pelvis angular speed squared
    w_balance: float = 0.0         # squared distance (m^2) of the capture point from the feet, while the target stands
    w_effort: float = 0.0          # mean squared correction (action units^2): what the feed-forward alone would not do
    threads: int = 2
    seed: int = 0
    warm_start: float = 1.0        # share of the last plan's correction the next one starts from: 1 keeps it (a
                                   # random walk of kept noise), 0 plans from the feed-forward alone (a label then
                                   # depends on the state, not on the history), between them it decays

    def __post_init__(self) -> None:
        for name in ("samples", "horizon", "execute", "knot_every", "threads", "iterations", "elites",
                     "chains"):
            if getattr(self, name) < 1:
                raise EnvError(f"planner {name} must be >= 1, got {getattr(self, name)}")
        if self.execute > self.horizon:
            raise EnvError(f"planner execute ({self.execute}) must be <= horizon ({self.horizon})")
        if self.elites > self.samples:
            raise EnvError(f"planner elites ({self.elites}) must be <= samples ({self.samples})")
        if not (self.noise >= 0 and self.rate >= 0 and self.blend_steps >= 1 and 0 < self.noise_decay <= 1
                and 0 <= self.warm_start <= 1):
            raise EnvError(f"planner noise and rate must be >= 0, blend_steps >= 1, noise_decay in (0, 1] and "
                           f"warm_start in [0, 1], got {self.noise}, {self.rate}, {self.blend_steps}, "
                           f"{self.noise_decay}, {self.warm_start}")

    def with_overrides(self, items: list[str]) -> PlannerConfig:
        """This config with `name=value` items applied (a script's `--planner iterations=4 elites=4`), each value
        read as its field's type; an unknown name or a value of the wrong type is an EnvError naming it."""
        types = {f.name: f.type for f in fields(self)}
        changes = {}
        for item in items:
            name, sep, value = item.partition("=")
            if not sep or name not in types:
                raise EnvError(f"planner override {item!r}: expected name=value with a name among {sorted(types)}")
            kind = {"int": int, "float": float}[types[name]]
            try:
                changes[name] = kind(value)
            except ValueError:
                raise EnvError(f"planner override {item!r}: {value!r} is not a {types[name]}") from None
            if not np.isfinite(changes[name]):
                raise EnvError(f"planner override {item!r}: the value must be finite")
        return replace(self, **changes)


@dataclass
class PlannedMotion:
    """What the env did: states before and after each action (T+1 rows), the T actions, their observations."""

    qpos: np.ndarray       # (T+1, 76)
    qvel: np.ndarray       # (T+1, 75)
    obs: np.ndarray        # (T+1, 358)
    actions: np.ndarray    # (T, 69), in [-1, 1], for the planner's action mapping: what was executed
    plan_costs: np.ndarray  # the chosen candidate's cost at each plan (the chains' mean): T / execute of them, T
                            # when a policy acted
    labels: np.ndarray     # (T, 69): the planner's own choice at each step; the actions unless a policy acted


def up_axis(quat: np.ndarray) -> np.ndarray:
    """World z axis of bodies whose orientations are the quaternions (..., 4) in MuJoCo's wxyz order."""
    w, x, y, z = np.moveaxis(quat, -1, 0)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)


class TrackingPlanner:
    """Tracks `reference` (F, 76) qpos frames from a given start; see the module docstring."""

    def __init__(self, reference: np.ndarray, cfg: PlannerConfig = PlannerConfig(),
                 action_mapping: str = DEFAULT_ACTION_MAPPING) -> None:
        ref = np.asarray(reference, dtype=np.float64)
        if ref.ndim != 2 or ref.shape[1] != NQ or len(ref) < 1:
            raise EnvError(f"planner reference must be qpos frames of shape (F, {NQ}), got {ref.shape}")
        if not np.isfinite(ref).all():
            raise EnvError("planner reference contains NaN or inf")
        self.reference, self.cfg = ref, cfg
        self.env = HumanoidEnv(max_episode_steps=10**9, action_mapping=action_mapping)
        self.amap = self.env.action_map
        self._model = sensing_model()
        self._datas = [mujoco.MjData(self._model) for _ in range(cfg.threads)]
        steps = np.arange(cfg.horizon)
        knots = np.arange(0, cfg.horizon + cfg.knot_every, cfg.knot_every)
        self._basis = np.maximum(0.0, 1.0 - np.abs(steps[:, None] / cfg.knot_every - np.arange(len(knots))[None]))

    def target(self, phase: np.ndarray) -> np.ndarray:
        """Reference qpos at fractional frame indices `phase` (H,), blended into the rest pose past the end."""
        last = len(self.reference) - 1
        i = np.clip(phase, 0, last)
        lo = np.floor(i).astype(int)
        hi = np.minimum(lo + 1, last)
        a = (i - lo)[:, None]
        q = self.reference[lo] * (1 - a) + self.reference[hi] * a
        b = np.clip((phase - last) / self.cfg.blend_steps, 0.0, 1.0)[:, None]
        q[:, 7:] = q[:, 7:] * (1 - b) + self.amap.center * b
        return q

    def nearest_frame(self, qpos: np.ndarray) -> int:
        """The reference frame closest to the pose `qpos` (76,) under the cost's pose, height and tilt terms."""
        return int(np.argmin(self.pose_error(self.reference, qpos[None])))

    def pose_error(self, qpos: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Weighted joint-angle, pelvis-height and tilt error of poses qpos (..., 76) against target (broadcast)."""
        c = self.cfg
        pose = ((qpos[..., 7:] - target[..., 7:]) ** 2).mean(-1)
        height = (qpos[..., 2] - target[..., 2]) ** 2
        tilt = 1.0 - (up_axis(qpos[..., 3:7]) * up_axis(target[..., 3:7])).sum(-1)
        return c.w_pose * pose + c.w_height * height + c.w_tilt * tilt

    def cost(self, qpos: np.ndarray, qvel: np.ndarray, sensed: np.ndarray, target: np.ndarray) -> np.ndarray:
        """(K,) summed cost of K predicted state sequences qpos (K, H, 76), qvel (K, H, 75) and their sensors
        (K, H, 18) against target (H, 76)."""
        c = self.cfg
        com, com_vel = sensed[..., 0:3], sensed[..., 3:6]
        feet = sensed[..., 6:18].reshape(*sensed.shape[:-1], len(_FEET), 3).mean(-2)
        capture = com[..., :2] + com_vel[..., :2] * np.sqrt(np.maximum(com[..., 2:3], 0.1) / 9.81)
        balance = ((capture - feet[..., :2]) ** 2).sum(-1) * (target[None, :, 2] > STANDING_TARGET)
        motion = (c.w_joint_speed * (qvel[..., 6:] ** 2).mean(-1) + c.w_root_speed * (qvel[..., :2] ** 2).sum(-1)
                  + c.w_root_spin * (qvel[..., 3:6] ** 2).sum(-1))
        return (self.pose_error(qpos, target[None]) + c.w_balance * balance + motion).sum(-1)

    def predicted_cost(self, state: np.ndarray, qacc_warmstart: np.ndarray, actions: np.ndarray,
                       target: np.ndarray) -> np.ndarray:
        """(K,) cost of K action sequences (K, H, 69), clipped to [-1, 1], each rolled out from the full physics
        `state` against target (H, 76)."""
        ctrl = np.repeat(self.amap.to_ctrl(np.clip(actions, -1.0, 1.0)), N_SUBSTEPS, axis=1)
        predicted, sensed = rollout.rollout(self._model, self._datas, state[None], ctrl,
                                            initial_warmstart=qacc_warmstart[None].copy())
        at = slice(N_SUBSTEPS - 1, None, N_SUBSTEPS)
        return self.cost(predicted[:, at, 1:1 + NQ], predicted[:, at, 1 + NQ:1 + NQ + NV], sensed[:, at], target)

    def run(self, qpos: np.ndarray, qvel: np.ndarray, steps: int, start_frame: float = 0.0,
            policy: Callable[[np.ndarray], np.ndarray] | None = None) -> PlannedMotion:
        """Plan and execute `steps` control steps from the state (qpos, qvel), the reference starting at
        `start_frame`. With a `policy` (observation -> action), the policy acts instead and the planner, replanning
        every step from the state the policy led to, only labels each state with its own choice (DAgger's expert:
        labels on the learner's states, where a clone of the planner's motions goes wrong). Each of those plans
        tracks the reference from its frame nearest the state (`nearest_frame`; `start_frame` is then unused), not
        from the step count: a policy still lying at step 60 gets the labels that start a rise, not those of the
        reference's frame 60, which stands (lab/log.md section 35)."""
        if steps < 1:
            raise EnvError(f"planner steps must be >= 1, got {steps}")
        qpos, qvel = check_state(qpos, qvel)
        c, env = self.cfg, self.env
        rng = np.random.default_rng(c.seed)
        obs, info = env.reset(options={"qpos": qpos, "qvel": qvel})
        qp, qv, ob, acts, labels, costs = [info["qpos"].copy()], [info["qvel"].copy()], [obs.copy()], [], [], []
        correction = np.zeros((c.chains, c.horizon, NU))
        state = np.empty(mujoco.mj_stateSize(env.model, _STATE))
        t = 0
        while t < steps:
            phase = start_frame + c.rate * t if policy is None else self.nearest_frame(env.data.qpos)
            target = self.target(phase + c.rate * (1 + np.arange(c.horizon)))
            feed = self.amap.from_angles(target[:, 7:]).astype(np.float64)
            mujoco.mj_getState(env.model, env.data, state, _STATE)
            for it in range(c.iterations):
                noise = rng.normal(scale=c.noise * c.noise_decay ** it,
                                   size=(c.chains, c.samples, self._basis.shape[1], NU))
                noise[:, 0] = 0.0
                candidates = correction[:, None] + np.einsum("hk,cskj->cshj", self._basis, noise)
                cost = (self.predicted_cost(state, env.data.qacc_warmstart,
                                            (feed + candidates).reshape(-1, c.horizon, NU), target)
                        + c.w_effort * np.square(candidates).mean(-1).sum(-1).reshape(-1))
                elite = np.argsort(cost.reshape(c.chains, c.samples), axis=1)[:, : c.elites]
                correction = np.take_along_axis(candidates, elite[..., None, None], axis=1).mean(1)
            costs.append(float(np.take_along_axis(cost.reshape(c.chains, -1), elite[:, :1], axis=1).mean()))
            plan = np.clip(feed + correction, -1.0, 1.0).mean(0)
            chosen = plan[:1 if policy is not None else min(c.execute, steps - t)]
            executed = (chosen if policy is None
                        else np.clip(check_action(policy(obs), (NU,), "policy action"), -1.0, 1.0)[None])
            for a, label in zip(executed, chosen):
                obs, _, _, _, info = env.step(a)
                acts.append(a.astype(np.float32))
                labels.append(label.astype(np.float32))
                qp.append(info["qpos"].copy())
                qv.append(info["qvel"].copy())
                ob.append(obs.copy())
            n = len(executed)
            t += n
            correction = c.warm_start * np.concatenate([correction[:, n:], np.repeat(correction[:, -1:], n, 1)], 1)
        return PlannedMotion(np.array(qp), np.array(qv), np.array(ob), np.array(acts), np.array(costs),
                             np.array(labels))
