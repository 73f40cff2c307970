"""Tracking refined by rollouts: a receding-horizon search over z with the simulator, the weights untouched.

Zero-shot tracking (`Prompt.track`) plays z_t = ER_FB of the next L reference states and never looks at where the
body is. Here the clip is cut into windows of `window` steps, and at each window, from the simulator's exact state
(a copy of the whole MuJoCo state, solver warm start included):

- a candidate is a centre c on the sqrt(d) sphere that plays z_t(c) = proj(z_t - z̄ + c) at step t, where z_t are
  the B-given z's and z̄ their projected mean over the window: c = z̄ plays the zero-shot z's exactly, and every
  candidate keeps their step-to-step changes;
- each candidate is rolled out `horizon` steps (reaching past the window, so a candidate that executes well but
  leaves the body falling loses), all candidates as one batch of envs, and costs the mean d_smpl between the
  states it reaches and the reference frames it should reach (a diverged simulation costs DIVERGED_COST a step);
- `fbcpr.inference.refine.cross_entropy` searches: `rounds` rounds of `candidates` centres, each round narrowing
  around the elites of the last, from z̄ (or, with `warm`, from z̄ shifted as the last window's kept centre was,
  z̄ then scored on its own); the cheapest candidate of any round is kept, so the kept one never costs more than
  zero-shot on the window's planning objective;
- optional: `position_weight` adds the step's mean body-position error (the MPJPE of one step, metres) to the
  planning cost; `leads` and `lookaheads` add starting centres (the B-given z's of a few steps later, for a body
  that lags; those of other lookahead lengths), scored with z̄ and the warm start, the search starting from the
  cheapest;
- the kept candidate's first `window` steps are executed (its simulator state after them is kept exactly, not
  simulated again) and the next window starts there.

A user sees cost as seconds of compute per second of motion (`TrackRefined.cost`).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from fbcpr.core.errors import PromptError
from fbcpr.inference.refine import Policy, Search, cross_entropy, project

#: Per-step cost of a simulation that diverged: above any d_smpl between two poses of the humanoid.
DIVERGED_COST = 20.0


@dataclass
class Receding:
    """The search's settings; `candidates` is the N of `--refine N`."""

    candidates: int = 32   # centres rolled out per round (one batch of envs)
    rounds: int = 3        # cross-entropy rounds per window, each narrowing around the last round's elites
    window: int = 8        # steps executed per window before searching again
    horizon: int = 24      # steps each candidate is rolled out and scored (>= window)
    sigma: float = 0.6     # the first round's perturbation scale (per z coordinate, on the sqrt(d) sphere)
    decay: float = 0.6     # sigma shrinks by this each round
    warm: bool = True      # start each window's search from the last window's shift (the B-given z's still a candidate)
    seed: int = 0
    position_weight: float = 0.0  # planning cost: d_smpl + this x the step's mean body-position error (metres)
    leads: tuple[int, ...] = ()   # also start from the B-given z's this many steps ahead (the body lags the clip)
    lookaheads: tuple[int, ...] = ()  # and from B-given z's of these lookahead lengths (`Prompt.track_refined`)

    def search(self, offset: int = 0) -> Search:
        """The cross-entropy settings of one window (its own noise: seed + offset)."""
        return Search(generations=self.rounds, population=self.candidates, sigma=self.sigma, decay=self.decay,
                      seed=self.seed + offset)

    def check(self) -> None:
        """Every setting in range, named when not (PromptError)."""
        for name in ("window", "horizon"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                raise PromptError(f"refine: {name} must be a positive integer, got {value!r}")
        if self.horizon < self.window:
            raise PromptError(f"refine: horizon ({self.horizon}) must be at least the window ({self.window}): "
                              "candidates are scored on the steps they would execute and after")
        if not np.isfinite(self.position_weight) or self.position_weight < 0:
            raise PromptError(f"refine: position_weight must be >= 0, got {self.position_weight!r}")
        for name, values in (("leads", self.leads), ("lookaheads", self.lookaheads)):
            if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1 for v in values):
                raise PromptError(f"refine: {name} must be positive integers, got {values!r}")
        for name, least in (("candidates", 2), ("rounds", 1)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < least:
                raise PromptError(f"refine: {name} must be an integer >= {least}, got {value!r}")
        self.search().check()  # sigma and decay, named


@dataclass
class TrackRefined:
    """What the search chose and executed: per-step z's, one centre per window, costs, the trajectory, the time."""

    zs: np.ndarray             # (T-1, d) the z played at every step (B-given after a divergence)
    window_z: np.ndarray       # (W, d) the kept centre of each window
    window_z0: np.ndarray      # (W, d) the B-given centre z̄ of each window
    plan_cost: np.ndarray      # (W,) the kept candidate's planning cost
    plan_cost0: np.ndarray     # (W,) the B-given candidate's planning cost
    obs: np.ndarray            # (T', obs_dim) states executed, obs[0] the clip's first state
    qpos: np.ndarray           # (T', nq)
    qvel: np.ndarray           # (T', nv)
    seconds: float             # wall-clock of the whole search
    cpu_seconds: float         # processor time of this process over it, every thread counted
    motion_seconds: float      # (T-1) / control rate
    rollouts: int              # candidate rollouts simulated
    diverged_at: int | None = None
    history: list[dict[str, float]] = field(default_factory=list)

    @property
    def cost(self) -> float:
        """Seconds of compute (wall-clock) per second of motion."""
        return self.seconds / max(self.motion_seconds, 1e-9)

    @property
    def cpu_cost(self) -> float:
        """Processor seconds per second of motion: the cost on a machine this process had to itself."""
        return self.cpu_seconds / max(self.motion_seconds, 1e-9)


class _Batches:
    """Batched envs by size (a round's candidates, the last round's single mean), loaded from one saved state."""

    def __init__(self, policy: Policy, steps: int, num_threads: int | None) -> None:
        self.policy, self.steps, self.num_threads = policy, steps, num_threads
        self.envs: dict[int, Any] = {}

    def env(self, k: int) -> Any:
        from humanoid_env.vector import VectorHumanoidEnv

        if k not in self.envs:
            self.envs[k] = VectorHumanoidEnv(k, max_episode_steps=self.steps, num_threads=self.num_threads,
                                             action_mapping=self.policy.action_mapping)
        return self.envs[k]

    def close(self) -> None:
        for env in self.envs.values():
            env.close()


def _tile(state: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    """One env's saved state (rows of length 1) repeated for k envs."""
    return {key: np.repeat(value, k, axis=0) for key, value in state.items()}


def _row(state: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    return {key: value[i:i + 1].copy() for key, value in state.items()}


def refine_track(policy: Policy, reference: np.ndarray, start: tuple[np.ndarray, np.ndarray], zs0: np.ndarray,
                 settings: Receding | None = None, num_threads: int | None = None,
                 on_window: Callable[[int, int], None] | None = None,
                 alternatives: np.ndarray | None = None) -> TrackRefined:
    """Track `reference` (T, obs_dim) from `start` = (qpos, qvel) of its first frame, refining the B-given z's `zs0`
    (T-1, d) window by window (see the module docstring). `alternatives` (S, T-1, d): other z sequences for the
    clip (e.g. other lookahead lengths) whose window means are scored as starting centres beside z̄.
    `on_window(done, total)` after every window."""
    from fbcpr.metrics import d_smpl
    from humanoid_env.model import CONTROL_HZ
    from humanoid_env.observation import BODY_POS

    settings = settings or Receding()
    settings.check()
    t0_clock, t0_cpu = time.perf_counter(), time.process_time()
    ref = np.asarray(reference, dtype=np.float32)
    zs0 = np.asarray(zs0, dtype=np.float64)
    steps = len(ref) - 1
    if ref.ndim != 2 or steps < 1:
        raise PromptError(f"refine: the reference must be (T >= 2, obs_dim) observations, got {ref.shape}")
    if zs0.shape != (steps, policy.z_dim):
        raise PromptError(f"refine: zs0 must be one z per step, ({steps}, {policy.z_dim}), got {zs0.shape}")
    qpos0, qvel0 = (np.asarray(x, dtype=np.float64)[None] for x in start)
    given = np.empty((0, steps, policy.z_dim)) if alternatives is None else np.asarray(alternatives, np.float64)
    if given.ndim != 3 or given.shape[1:] != (steps, policy.z_dim):
        raise PromptError(f"refine: alternatives must be (S, {steps}, {policy.z_dim}), got {given.shape}")
    leads = [zs0[np.minimum(np.arange(steps) + k, steps - 1)][None] for k in settings.leads]
    alts = np.concatenate([given, *leads])  # (S', steps, d): every other z sequence whose window means start a search
    w_pos = settings.position_weight
    ref_pos = ref[:, BODY_POS].reshape(len(ref), -1, 3)
    window, horizon, k = settings.window, settings.horizon, settings.candidates
    n_windows = -(-steps // window)
    batches = _Batches(policy, steps + horizon + 1, num_threads)
    # the batched envs carry the parallelism; a round's forward pass is a few small matmuls, which more torch
    # threads only slow down (on 2 cores, 6-20x per call, spinning against the simulation's threads)
    torch_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        single = batches.env(1)
        first_obs, info = single.reset(options={"qpos": qpos0, "qvel": qvel0})
        state = single.save_state()
        obs, qpos, qvel = [first_obs[0]], [info["qpos"][0]], [info["qvel"][0]]
        zs = zs0.astype(np.float32).copy()
        window_z: list[np.ndarray] = []
        window_z0: list[np.ndarray] = []
        cost: list[float] = []
        cost0: list[float] = []
        history: list[dict[str, float]] = []
        rollouts, diverged_at = 0, None
        for w in range(n_windows):
            t0 = w * window
            e, h = min(window, steps - t0), min(horizon, steps - t0)
            z_b = zs0[t0:t0 + h]                                 # (h, d) B-given z's over the horizon
            z_bar = project(z_b[:e].mean(0)[None])[0]
            target = ref[t0 + 1:t0 + 1 + h]                      # frames the h steps should reach
            target_pos = ref_pos[t0 + 1:t0 + 1 + h]
            best: dict[str, Any] = {"cost": np.inf}

            def score(cands: np.ndarray) -> np.ndarray:
                """-(mean d_smpl over the horizon) of each centre, rolled out as one batch from `state`."""
                n = len(cands)
                env = batches.env(n)
                o = env.load_state(_tile(state, n))
                z = project((z_b[None] - z_bar[None, None] + cands[:, None]).reshape(n * h, -1))
                z = z.reshape(n, h, -1).astype(np.float32)
                total, alive = np.zeros(n), np.ones(n, bool)
                lived = np.full(n, e)  # executed steps each candidate took before its simulation diverged
                trail = [np.empty((n, e, dim)) for dim in (ref.shape[1], qpos0.shape[1], qvel0.shape[1])]
                snap: dict[str, np.ndarray] = {}
                for j in range(h):
                    o, _, _, _, inf = env.step(np.asarray(policy.act(o, z[:, j], mean=True), dtype=np.float32))
                    alive &= ~inf["diverged"]
                    step_cost = d_smpl(inf["final_obs"], target[j])
                    if w_pos:
                        pos = inf["final_obs"][:, BODY_POS].reshape(n, -1, 3)
                        step_cost = step_cost + w_pos * np.linalg.norm(pos - target_pos[j], axis=-1).mean(-1)
                    total += np.where(alive, step_cost, DIVERGED_COST)
                    if j < e:
                        lived = np.where(~alive & (lived == e), j, lived)
                        for part, key in zip(trail, ("final_obs", "final_qpos", "final_qvel")):
                            part[:, j] = inf[key]
                    if j == e - 1:
                        snap = env.save_state()
                mean_cost = total / h
                i = int(np.argmin(mean_cost))
                if mean_cost[i] < best["cost"]:
                    best.update(cost=float(mean_cost[i]), z=z[i, :e], centre=cands[i], state=_row(snap, i),
                                trail=[part[i, :lived[i]] for part in trail], lived=int(lived[i]))
                if "cost0" not in best:
                    best["cost0"] = float(mean_cost[0])  # the first row scored: z̄, the B-given candidate
                return -mean_cost

            # z̄ is always scored (the B-given z's stay a candidate); the search starts from the last window's shift
            # carried over (warm), or, given alternatives, from the cheapest of those and their window means
            starts = [z_bar]
            if settings.warm and window_z:
                starts.append(project((z_bar + window_z[-1] - window_z0[-1])[None])[0])
            if len(alts):
                starts += list(project(alts[:, t0:t0 + e].mean(1)))
                start_z = starts[int(np.argmax(score(np.stack(starts))))]
            else:
                start_z = starts[-1]
                if len(starts) > 1:
                    score(z_bar[None])
            rollouts += len(starts) if len(alts) else len(starts) - 1
            refined = cross_entropy(score, start_z, settings.search(w))
            rollouts += k * settings.rounds + 1
            history += [{"window": float(w), **row} for row in refined.history]
            zs[t0:t0 + e] = best["z"]
            window_z.append(best["centre"].astype(np.float32))
            window_z0.append(z_bar.astype(np.float32))
            cost.append(best["cost"])
            cost0.append(best["cost0"])
            for part, seen in zip((obs, qpos, qvel), best["trail"]):
                part += list(seen)
            state = best["state"]
            if on_window is not None:
                on_window(w + 1, n_windows)
            if best["lived"] < e:
                diverged_at = t0 + best["lived"]
                break
    finally:
        batches.close()
        torch.set_num_threads(torch_threads)
    return TrackRefined(zs=zs, window_z=np.stack(window_z), window_z0=np.stack(window_z0),
                        plan_cost=np.asarray(cost), plan_cost0=np.asarray(cost0),
                        obs=np.stack(obs).astype(np.float32), qpos=np.stack(qpos), qvel=np.stack(qvel),
                        seconds=time.perf_counter() - t0_clock, cpu_seconds=time.process_time() - t0_cpu,
                        motion_seconds=steps / CONTROL_HZ,
                        rollouts=rollouts, diverged_at=diverged_at, history=history)
