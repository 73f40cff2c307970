"""Gymnasium environment for one SMPL humanoid: PD control at 30 Hz on a 450 Hz MuJoCo simulation.

An action in [-1, 1]^69 is a PD target placed on each joint's range (the actuators' ctrlrange equals the joint range) by
the env's action mapping (`humanoid_env.actions`: `rest`, the default, or `mid`). One step runs `mujoco.mj_step` for 15
substeps; the observation comes from the one observation function (`humanoid_env.observation`). A simulation that
diverges (MuJoCo warnings, NaN or huge velocities) ends the episode with the last good observation and
`info["diverged"] = True`; nothing raises.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np

from humanoid_env.actions import DEFAULT_ACTION_MAPPING, ActionMap, check_action
from humanoid_env.errors import EnvError, InvalidStateError
from humanoid_env.model import CONTROL_HZ, N_SUBSTEPS, NQ, NU, NV, load_model
from humanoid_env.observation import OBS_DIM, assemble, read_kinematics

if TYPE_CHECKING:
    from humanoid_env.render import TrackRenderer

#: RewardFn(obs (N,358), action (N,69) | None, qpos (N,76), qvel (N,75)) -> (N,), on the next state.
RewardFn = Callable[[np.ndarray, "np.ndarray | None", np.ndarray, np.ndarray], np.ndarray]
#: TerminationFn(obs (N,358), qpos (N,76), qvel (N,75)) -> (N,) bool, on the next state.
TerminationFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]

#: Warnings that mean the state was unusable (MuJoCo then resets the data on its own).
DIVERGENCE_WARNINGS = (
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
)
#: Simulation time at the start of an episode. MuJoCo resets a simulation that went bad to time 0 (and does
#: not always leave a warning count behind), so a clock below this start means the state was thrown away.
EPISODE_START_TIME = 1.0
#: Default bound on |qvel| (m/s for the root, rad/s for hinges) beyond which a simulation counts as diverged.
MAX_QVEL = 500.0
DEFAULT_EPISODE_STEPS = 300
#: Pelvis height (m) below which the body counts as fallen (evaluation's upright time uses the same line).
FALLEN_HEIGHT = 0.6


def check_reset_fallen(steps: int) -> int:
    """Validate `reset_fallen_after` (env steps spent fallen before the episode ends; 0: never)."""
    if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or steps < 0:
        raise EnvError(f"reset_fallen_after must be an int >= 0 (env steps; 0 = off), got {steps!r}")
    return int(steps)


class FallenClock:
    """Per env, how long the pelvis has been below `FALLEN_HEIGHT` in a row, and whether that ends the episode:
    after `reset_fallen_after` steps (0: never); with `once_up`, only once it has been up that long in a row in
    this episode, so a fall start (which lies at once) keeps its whole episode to get up."""

    def __init__(self, num_envs: int, reset_fallen_after: int, once_up: bool) -> None:
        self.after, self.once_up = check_reset_fallen(reset_fallen_after), bool(once_up)
        self.fallen, self.up = np.zeros(num_envs, np.int64), np.zeros(num_envs, np.int64)
        self.armed = np.zeros(num_envs, bool)

    def reset(self, ids: Any = slice(None)) -> None:
        self.fallen[ids] = self.up[ids] = 0
        self.armed[ids] = False

    def step(self, pelvis_heights: np.ndarray) -> np.ndarray:
        """Count one step; (num_envs,) mask of the envs that have now lain fallen long enough."""
        low = np.asarray(pelvis_heights) < FALLEN_HEIGHT
        self.fallen = np.where(low, self.fallen + 1, 0)
        self.up = np.where(low, 0, self.up + 1)
        if not self.after:
            return np.zeros(len(low), bool)
        self.armed |= self.up >= self.after
        return (self.fallen >= self.after) & (self.armed | (not self.once_up))


def reset_fallen_steps(seconds: float) -> int:
    """`reset_fallen_after` for a time in seconds: whole control steps, at least one when the reset is on."""
    return max(round(seconds * CONTROL_HZ), int(seconds > 0))


class InitSampler(Protocol):
    """Anything that draws initial states: `humanoid_env.inits` samplers or a motion library."""

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]: ...


def resolve_reward(reward: RewardFn | str | None) -> RewardFn | None:
    """A reward callable from a callable or a task name (looked up lazily in `humanoid_env.tasks`)."""
    if reward is None or callable(reward):
        return reward
    if isinstance(reward, str):
        from humanoid_env.tasks import get_reward  # lazy: the env works without the task registry

        return get_reward(reward)
    raise TypeError(f"reward must be a callable, a task name or None, got {type(reward).__name__}")


def check_state(qpos: Any, qvel: Any, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Validate a user-given state: shapes (n,76)/(n,75) (or (76,)/(75,) when n is None) and finite values."""
    qp, qv = np.asarray(qpos, dtype=np.float64), np.asarray(qvel, dtype=np.float64)
    want_p, want_v = ((NQ,), (NV,)) if n is None else ((n, NQ), (n, NV))
    if qp.shape != want_p or qv.shape != want_v:
        raise InvalidStateError(f"reset options: expected qpos {want_p} and qvel {want_v}, got {qp.shape} and "
                                f"{qv.shape}")
    if not (np.isfinite(qp).all() and np.isfinite(qv).all()):
        raise InvalidStateError("reset options: qpos and qvel must be finite (found NaN or inf)")
    return qp, qv


def _state_options(options: dict | None) -> tuple[Any, Any] | None:
    if not options or ("qpos" not in options and "qvel" not in options):
        return None
    if "qpos" not in options or "qvel" not in options:
        raise InvalidStateError("reset options: give both 'qpos' and 'qvel' to set an exact state")
    return options["qpos"], options["qvel"]


class HumanoidEnv(gym.Env):
    """One SMPL humanoid. `reset(options={"qpos", "qvel"})` sets an exact state; `info` holds qpos/qvel copies."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        init: InitSampler | None = None,
        reward: RewardFn | str | None = None,
        termination: TerminationFn | None = None,
        max_episode_steps: int = DEFAULT_EPISODE_STEPS,
        max_qvel: float = MAX_QVEL,
        render_mode: str | None = None,
        width: int = 320,
        height: int = 240,
        action_mapping: str = DEFAULT_ACTION_MAPPING,
        reset_fallen_after: int = 0,
        fallen_terminates: bool = False,
        reset_fallen_once_up: bool = False,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise EnvError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if max_episode_steps < 1:
            raise EnvError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        from humanoid_env.inits import DefaultInit

        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        self.init = init if init is not None else DefaultInit()
        self.reward_fn = resolve_reward(reward)
        self.termination_fn = termination
        self.max_episode_steps = int(max_episode_steps)
        self._clock = FallenClock(1, reset_fallen_after, reset_fallen_once_up)
        self.fallen_terminates = bool(fallen_terminates)
        self.max_qvel = float(max_qvel)
        self.render_mode = render_mode
        self._size = (height, width)
        self._renderer: TrackRenderer | None = None
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (NU,), np.float32)
        self.action_map = ActionMap(self.model, action_mapping)
        self._act = np.empty(NU)
        self._obs = np.zeros(OBS_DIM, np.float32)
        self._good_qpos, self._good_qvel = self.data.qpos.copy(), self.data.qvel.copy()
        self._steps = 0

    @property
    def reset_fallen_after(self) -> int:
        return self._clock.after

    @property
    def reset_fallen_once_up(self) -> bool:
        return self._clock.once_up

    def _observe(self) -> np.ndarray:
        xpos, xmat, cvel, com = read_kinematics(self.model, self.data)
        return assemble(xpos[None], xmat[None], cvel[None], com[None])[0]

    def _info(self, diverged: bool) -> dict[str, Any]:
        if diverged:  # the state of the last good observation, not what MuJoCo reset the data to
            return {"qpos": self._good_qpos.copy(), "qvel": self._good_qvel.copy(), "diverged": True}
        self._good_qpos, self._good_qvel = self.data.qpos.copy(), self.data.qvel.copy()
        return {"qpos": self._good_qpos, "qvel": self._good_qvel, "diverged": False}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        state = _state_options(options)
        if state is None:
            qpos, qvel = self.init.sample(self.np_random, 1)
            qpos, qvel = check_state(qpos[0], qvel[0])
        else:
            qpos, qvel = check_state(*state)
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        self.data.time = EPISODE_START_TIME
        mujoco.mj_forward(self.model, self.data)
        self._steps = 0
        self._clock.reset()
        obs = self._observe()
        if not np.isfinite(obs).all():
            raise InvalidStateError("reset: the state's observation is not finite (qpos/qvel beyond float32 range?)")
        self._obs = obs
        return self._obs, self._info(False)

    def _diverged(self, obs: np.ndarray) -> bool:
        # MuJoCo answers a bad qpos/qvel/qacc with a warning and a reset of the data, which sets the clock to 0
        if self.data.time < EPISODE_START_TIME:
            return True
        return not (np.abs(self.data.qvel).max() <= self.max_qvel and np.isfinite(obs.sum()))  # NaN fails <=

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        np.clip(check_action(action, (NU,), "action"), -1.0, 1.0, out=self._act)
        self.action_map.to_ctrl(self._act, out=self.data.ctrl)
        mujoco.mj_step(self.model, self.data, nstep=N_SUBSTEPS)
        self._steps += 1
        obs = self._observe()
        diverged = self._diverged(obs)
        if diverged:
            obs = self._obs  # the last good observation: never hand out NaN
        self._obs = obs
        info = self._info(diverged)
        reward = 0.0
        terminated = diverged
        if not diverged:
            if self.reward_fn is not None:
                reward = float(self.reward_fn(obs[None], self._act[None].astype(np.float32), info["qpos"][None],
                                              info["qvel"][None])[0])
            if self.termination_fn is not None:
                terminated = bool(self.termination_fn(obs[None], info["qpos"][None], info["qvel"][None])[0])
        lain = bool(self._clock.step(info["qpos"][None, 2])[0])
        terminated = terminated or (lain and self.fallen_terminates)
        truncated = self._steps >= self.max_episode_steps or (lain and not self.fallen_terminates)
        return obs, reward, terminated, truncated, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from humanoid_env.render import TrackRenderer

        if self._renderer is None:
            self._renderer = TrackRenderer(self.model, *self._size)
        return self._renderer.render(self.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
