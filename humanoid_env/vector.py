"""Batched SMPL humanoid: N simulations stepped on MuJoCo's native thread pool (`mujoco.batch.Batch`).

No per-env Python: controls, stepping (threads in C, results bit-identical to one MjData per env at any
thread count), kinematics at the new state and the observation of all envs happen in a few batched calls.
Autoreset mode is SAME_STEP: when an episode ends, the returned observation is already the next episode's
first one, and `info["final_obs"]`, `info["final_qpos"]`, `info["final_qvel"]` hold the state the step
reached, for every env (for envs not done it equals the returned one; `info["_final_obs"]` marks the done envs).
"""
from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from mujoco import batch as mjbatch

from humanoid_env.actions import DEFAULT_ACTION_MAPPING, ActionMap, check_action
from humanoid_env.env import (
    DEFAULT_EPISODE_STEPS,
    DIVERGENCE_WARNINGS,
    EPISODE_START_TIME,
    MAX_QVEL,
    FallenClock,
    InitSampler,
    RewardFn,
    TerminationFn,
    _state_options,
    check_state,
    resolve_reward,
)
from humanoid_env.errors import EnvError, InvalidStateError
from humanoid_env.model import N_SUBSTEPS, NU, load_model
from humanoid_env.observation import N_BODIES, OBS_DIM, assemble

_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)


class VectorHumanoidEnv(VectorEnv):
    """num_envs humanoids on num_threads threads (None: all cores); same seed, same rollouts."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        init: InitSampler | None = None,
        num_threads: int | None = None,
        reward: RewardFn | str | None = None,
        termination: TerminationFn | None = None,
        max_episode_steps: int = DEFAULT_EPISODE_STEPS,
        max_qvel: float = MAX_QVEL,
        action_mapping: str = DEFAULT_ACTION_MAPPING,
        reset_fallen_after: int = 0,
        fallen_terminates: bool = False,
        reset_fallen_once_up: bool = False,
    ) -> None:
        if num_envs < 1:
            raise EnvError(f"num_envs must be >= 1, got {num_envs}")
        if max_episode_steps < 1:
            raise EnvError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        if num_threads is not None and num_threads < 1:
            raise EnvError(f"num_threads must be >= 1 or None (all cores), got {num_threads}")
        from humanoid_env.inits import DefaultInit

        self.num_envs = int(num_envs)
        self.model = load_model()
        self.init = init if init is not None else DefaultInit()
        self.reward_fn = resolve_reward(reward)
        self.termination_fn = termination
        self.max_episode_steps = int(max_episode_steps)
        self._clock = FallenClock(self.num_envs, reset_fallen_after, reset_fallen_once_up)
        self.fallen_terminates = bool(fallen_terminates)
        self.max_qvel = float(max_qvel)
        self.render_mode = None
        self.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (NU,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

        self.batch = mjbatch.Batch(self.model, self.num_envs, nthread=num_threads or 0)
        b = self.batch
        self._qpos, self._qvel, self._ctrl, self._time = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl"), b.bind("time")
        self._xpos, self._xmat, self._cvel = b.bind("xpos"), b.bind("xmat"), b.bind("cvel")
        self._com = b.bind("subtree_com")
        self.action_map = ActionMap(self.model, action_mapping)
        self._act = np.empty((self.num_envs, NU))
        self._obs = np.zeros((self.num_envs, OBS_DIM), np.float32)
        self._good_qpos, self._good_qvel = self._qpos.copy(), self._qvel.copy()
        self._steps = np.zeros(self.num_envs, np.int64)
        self._np_random, self._np_random_seed = seeding.np_random(None)

    def get_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of (qpos, qvel, steps into the episode) of every env; an env whose simulation diverged gives its
        last finite state. `reset(options={"qpos", "qvel"})` and `set_episode_steps` put them back."""
        return self._good_qpos.copy(), self._good_qvel.copy(), self._steps.copy()

    def set_episode_steps(self, steps: np.ndarray) -> None:
        """The steps each env's episode has run (a resumed run truncates its episodes where they would have)."""
        self._steps[:] = steps

    def save_state(self) -> dict[str, np.ndarray]:
        """Everything the next steps depend on, as copies: each simulation's whole MuJoCo integration state (a
        `mujoco.batch` state row: time, qpos, qvel, the constraint solver's warm start, controls, ... as
        mj_getState gives it), its warning counters, the last observation, the steps into each episode and the
        fallen clocks. `load_state` puts it back, after which the envs step exactly as these would have: qpos and
        qvel alone would lose the solver's warm start, and with it the last bits of the next states."""
        c = self._clock
        return {"physics": self.batch.state.copy(), "warnings": np.array(self.batch.warning), "obs": self._obs.copy(),
                "steps": self._steps.copy(), "fallen": c.fallen.copy(), "up": c.up.copy(), "armed": c.armed.copy()}

    def load_state(self, state: dict[str, np.ndarray]) -> np.ndarray:
        """Restore what `save_state` gave (of a batch of the same size and MuJoCo build); returns the observation.
        InvalidStateError naming the entry when one is missing, of another shape, or not finite."""
        b, n = self.batch, self.num_envs
        shapes = {"physics": b.state.shape, "warnings": b.warning.shape, "obs": self._obs.shape, "steps": (n,),
                  "fallen": (n,), "up": (n,), "armed": (n,)}
        for key, shape in shapes.items():
            if key not in state:
                raise InvalidStateError(f"env state: missing {key!r}")
            if tuple(np.shape(state[key])) != tuple(shape):
                raise InvalidStateError(f"env state: {key!r} has shape {tuple(np.shape(state[key]))}, this env's is "
                                        f"{tuple(shape)} (another num_envs or another MuJoCo build)")
        if not (np.isfinite(state["physics"]).all() and np.isfinite(state["obs"]).all()):
            raise InvalidStateError("env state: 'physics' or 'obs' is not finite")
        b.state[:] = state["physics"]
        b.warning[:] = state["warnings"]
        b.forward(stage=_VEL)  # derived fields at the restored state (the state rows themselves are left as they are)
        self._obs = np.array(state["obs"], dtype=np.float32)
        self._good_qpos, self._good_qvel = self._qpos.copy(), self._qvel.copy()
        self._steps[:] = state["steps"]
        self._clock.fallen[:], self._clock.up[:] = state["fallen"], state["up"]
        self._clock.armed[:] = state["armed"]
        return self._obs.copy()

    @property
    def reset_fallen_after(self) -> int:
        return self._clock.after

    @property
    def reset_fallen_once_up(self) -> bool:
        return self._clock.once_up

    def _observe(self, ids: np.ndarray | None = None) -> np.ndarray:
        sel = slice(None) if ids is None else ids
        xmat = self._xmat[sel, 1:].reshape(-1, N_BODIES, 3, 3)
        return assemble(self._xpos[sel, 1:], xmat, self._cvel[sel, 1:], self._com[sel, 1])

    def _set_states(self, ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Reset envs ids to exact states and compute their observations."""
        self.batch.reset(ids, stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        self._qpos[ids] = qpos
        self._qvel[ids] = qvel
        self._time[ids] = EPISODE_START_TIME
        self.batch.warning[ids] = 0
        self.batch.forward(ids, stage=_VEL)
        obs = self._observe(ids)
        bad = ~np.isfinite(obs).all(axis=1)
        if bad.any():
            raise InvalidStateError(f"reset: the observation of envs {np.asarray(ids)[bad].tolist()} is not finite "
                             "(qpos/qvel beyond float32 range?)")
        self._obs[ids] = obs
        self._good_qpos[ids], self._good_qvel[ids] = qpos, qvel
        self._steps[ids] = 0
        self._clock.reset(ids)

    def _sample(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        qpos, qvel = self.init.sample(self.np_random, k)
        return check_state(qpos, qvel, k)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            if not isinstance(seed, (int, np.integer)):
                raise TypeError(f"seed must be an int or None, got {type(seed).__name__}")
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        state = _state_options(options)
        qpos, qvel = self._sample(self.num_envs) if state is None else check_state(*state, self.num_envs)
        self._set_states(np.arange(self.num_envs), qpos, qvel)
        info = {"qpos": self._qpos.copy(), "qvel": self._qvel.copy(), "diverged": np.zeros(self.num_envs, bool)}
        return self._obs.copy(), info

    def _advance(self) -> np.ndarray:
        """Step all sims 15 substeps; (N,) mask of sims MuJoCo refused to step (they keep their state)."""
        try:
            self.batch.step(nstep=N_SUBSTEPS, stage=_VEL)
        except mjbatch.SimulationError as err:
            failed = np.zeros(self.num_envs, bool)
            failed[err.ids] = True
            return failed
        return np.zeros(self.num_envs, bool)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        np.clip(check_action(actions, (self.num_envs, NU), "actions"), -1.0, 1.0, out=self._act)
        self.action_map.to_ctrl(self._act, out=self._ctrl)
        failed = self._advance()

        obs = self._observe()
        warn = self.batch.warning
        diverged = failed | (warn[:, DIVERGENCE_WARNINGS, 0] > 0).any(1) | (self._time < EPISODE_START_TIME)
        diverged |= ~np.isfinite(obs).all(1) | (np.abs(self._qvel).max(1) > self.max_qvel)
        qpos, qvel = self._qpos.copy(), self._qvel.copy()
        if diverged.any():  # keep the last good state and observation: never hand out NaN
            warn[diverged] = 0
            obs[diverged], qpos[diverged], qvel[diverged] = (self._obs[diverged], self._good_qpos[diverged],
                                                             self._good_qvel[diverged])

        if self.reward_fn is not None:
            reward = np.asarray(self.reward_fn(obs, self._act.astype(np.float32), qpos, qvel),
                                dtype=np.float64).reshape(self.num_envs)
            reward[diverged] = 0.0
        else:
            reward = np.zeros(self.num_envs)
        terminated = diverged.copy()
        if self.termination_fn is not None:
            terminated |= np.asarray(self.termination_fn(obs, qpos, qvel), dtype=bool).reshape(self.num_envs)
        self._steps += 1
        lain = self._clock.step(qpos[:, 2])
        truncated = self._steps >= self.max_episode_steps
        if self.fallen_terminates:
            terminated |= lain
        else:
            truncated |= lain
        done = terminated | truncated

        self._obs, self._good_qpos, self._good_qvel = obs, qpos, qvel
        info: dict[str, Any] = {"diverged": diverged, "final_obs": obs.copy(), "final_qpos": qpos, "final_qvel": qvel,
                                "_final_obs": done}
        ids = np.flatnonzero(done)
        if len(ids):
            self._good_qpos, self._good_qvel = qpos.copy(), qvel.copy()
            self._set_states(ids, *self._sample(len(ids)))
        info["qpos"], info["qvel"] = self._good_qpos.copy(), self._good_qvel.copy()
        return self._obs.copy(), reward, terminated, truncated, info
