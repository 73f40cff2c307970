"""Environment factory for the trainer: builds the batched env and its demonstrations from an `EnvConfig`.

Which env a config names is looked up in the registry (`fbcpr.core.registry.ENVS`). The trainer only sees an
`EnvBundle` (a Gymnasium VectorEnv with the humanoid's info conventions, a
library with `sample_windows` / `sample_states` / `set_priorities_from_emd`, and per-clip reference
trajectories), so it never knows how clips were imported or which environment it is training on.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fbcpr.core.config import DATA_VAR
from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import EnvBundle, StateObserver, TaskReward
from fbcpr.core.registry import LATENT_ACTIONS, env_kind, load
from fbcpr.core.schema import EnvConfig
from fbcpr.metrics import emd, tracking_success


def _task_error(err: Exception) -> ConfigError:
    return ConfigError(f"agent.reward.task: {err.args[0]}")


def humanoid_observer() -> StateObserver:
    """The humanoid's observation as a function of the state (by kinematics): with it a reward-inference sample
    ships as states only (its observations are rebuilt on load, a third of the size)."""
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe

    model = load_model()

    def humanoid(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        qpos = np.array(qpos, dtype=np.float64)
        qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)  # float16 storage denormalises it
        return observe(model, qpos, qvel)

    return humanoid


def make_env(cfg: EnvConfig, num_envs: int, seed: int, threads: int | None = None) -> EnvBundle:
    """Build the configured environment (`humanoid` or `toy`) with `num_envs` parallel copies, stepped on `threads`
    threads (None: all cores; data-parallel ranks on one machine share them). With `env.npmp`, the agent acts in
    that NPMP's latent space (`fbcpr.apps.npmp.reuse`)."""
    bundle = env_kind(cfg.name).make(cfg, num_envs, threads)
    return bundle if cfg.npmp is None else load(LATENT_ACTIONS)(bundle, cfg)


def _focus_library(cfg: EnvConfig, lib: Any) -> Any:
    """The clips of env.focus_clips or env.focus_motions, as a library of their own (each clip equally likely), or
    None."""
    from motions.library import MotionLibrary

    if cfg.focus_motions:
        path = Path(cfg.focus_motions)
        if not path.exists():
            raise ConfigError(f"env.focus_motions: {path} does not exist (give a clip .npz or a folder of them)")
        try:
            return MotionLibrary.load([path] if path.is_file() else path)
        except ValueError as err:  # ClipFormatError included: the message names the file
            raise ConfigError(f"env.focus_motions: {err}") from None
    if not cfg.focus_clips:
        return None
    unknown = [n for n in cfg.focus_clips if n not in lib.names]
    if unknown:
        raise ConfigError(f"env.focus_clips: {unknown[0]!r} is not a clip of env.motions ({cfg.motions}); its clips "
                          f"are {lib.names}")
    return MotionLibrary([c for c in lib.clips if c.name in cfg.focus_clips])


def humanoid_bundle(cfg: EnvConfig, num_envs: int, threads: int | None = None) -> EnvBundle:
    """The SMPL humanoid on the clips of `env.motions` (`env.name: humanoid`)."""
    from humanoid_env import NQ, NU, NV, OBS_DIM
    from humanoid_env.env import reset_fallen_steps
    from humanoid_env.inits import make_init
    from humanoid_env.vector import VectorHumanoidEnv
    from motions.library import MotionLibrary

    if cfg.motions == "synthetic":
        from motions.synthetic import default_library

        lib = default_library()
    else:
        path = Path(cfg.motions)
        if not path.exists():
            raise ConfigError(f"env.motions: {path} does not exist (give a clip .npz, a folder of them or "
                              f"'synthetic'; the shipped configs read clips from the data directory, "
                              f"${DATA_VAR} or ./data: `fbcpr motions import ... --out {path}` makes them)")
        lib = MotionLibrary.load([path] if path.is_file() else path)  # one clip: single-demonstration imitation

    def task_reward(name: str) -> TaskReward:
        from humanoid_env.tasks import get_reward  # lazy: the task registry needs dm_control, FB-CPR training does not

        try:
            fn = get_reward(name)
        except ValueError as err:
            raise _task_error(err) from None
        return lambda next_obs, qpos, qvel: fn(next_obs, None, qpos, qvel)

    return EnvBundle(
        env=VectorHumanoidEnv(num_envs, init=make_init(cfg.fall_prob, mocap=lib, stand_prob=cfg.stand_prob,
                                                       focus=_focus_library(cfg, lib), focus_prob=cfg.focus_prob),
                              max_episode_steps=cfg.max_episode_steps,
                              action_mapping=cfg.action_mapping, num_threads=threads,
                              reset_fallen_after=reset_fallen_steps(cfg.reset_fallen_s),
                              fallen_terminates=cfg.fallen_terminates,
                              reset_fallen_once_up=cfg.reset_fallen_once_up),
        library=lib, obs_dim=OBS_DIM, action_dim=NU, nq=NQ, nv=NV,
        make_eval_env=lambda n, steps: VectorHumanoidEnv(n, max_episode_steps=steps, action_mapping=cfg.action_mapping),
        clip_obs=lambda i: lib.clips[i].obs,
        clip_start=lambda i: (lib.clips[i].qpos[0], lib.clips[i].qvel[0]),
        emd=emd, success=tracking_success, task_reward=task_reward,
    )
