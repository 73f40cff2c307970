"""Environment factory for the trainer: builds the batched env and its demonstrations from an `EnvConfig`.

The trainer only sees an `EnvBundle` (a Gymnasium VectorEnv with the humanoid's info conventions, a
library with `sample_windows` / `sample_states` / `set_priorities_from_emd`, and per-clip reference
trajectories), so it never knows how clips were imported or which environment it is training on.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from fbcpr.core.config import ConfigError, EnvConfig
from fbcpr.nn.latents import tracking_sums
from fbcpr.nn.networks import project_sphere


#: A registry reward on next states: (next_obs (N, obs_dim), qpos (N, nq), qvel (N, nv)) -> (N,).
TaskReward = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _task_error(err: Exception) -> ConfigError:
    return ConfigError(f"agent.reward.task: {err.args[0]}")


@dataclass
class EnvBundle:
    env: Any                                              # gymnasium VectorEnv, SAME_STEP autoreset
    library: Any                                          # demonstrations (MotionLibrary-like)
    obs_dim: int
    action_dim: int
    nq: int
    nv: int
    make_eval_env: Callable[[int, int], Any]              # (num_envs, max_episode_steps) -> VectorEnv
    clip_obs: Callable[[int], np.ndarray]                 # clip index -> (T, obs_dim) reference observations
    clip_start: Callable[[int], tuple[np.ndarray, np.ndarray]]  # clip index -> (qpos, qvel) of frame 0
    emd: Callable[[np.ndarray, np.ndarray], float]        # tracking EMD between two (T, obs_dim) trajectories
    success: Callable[[np.ndarray, np.ndarray], bool]     # tracking success (time-aligned)
    task_reward: Callable[[str], TaskReward]              # registry task name -> reward of (next_obs, qpos, qvel)


#: Observations of states: (qpos (N, nq), qvel (N, nv)) -> next_obs (N, obs_dim) float32.
StateObserver = Callable[[np.ndarray, np.ndarray], np.ndarray]


def state_observer(env_name: str) -> StateObserver:
    """The env's observation as a function of the state (both envs observe their state alone, by kinematics).

    With it a reward-inference sample can ship as states only (its observations are rebuilt on load, a third of
    the size), and a sample's rows can be checked to be single transitions (`inconsistent_rows`)."""
    if env_name == "toy":
        from fbcpr.envs.toy import observe as toy_observe

        return toy_observe
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe

    model = load_model()

    def humanoid(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        qpos = np.array(qpos, dtype=np.float64)
        qpos[:, 3:7] /= np.linalg.norm(qpos[:, 3:7], axis=1, keepdims=True)  # float16 storage denormalises it
        return observe(model, qpos, qvel)

    return humanoid


def inconsistent_rows(buf: dict[str, np.ndarray], env_name: str, rows: int = 64) -> float:
    """Share of the first `rows` rows whose next_obs is not the observation of their own (qpos, qvel), to float16
    precision (0.0 for an empty sample). Rows mixed across transitions score about 1.0."""
    n = min(rows, len(buf["qpos"]))
    if n == 0:
        return 0.0
    rebuilt = state_observer(env_name)(buf["qpos"][:n], buf["qvel"][:n])
    stored = np.asarray(buf["next_obs"][:n], dtype=np.float32)
    ok = np.isclose(rebuilt, stored, rtol=0.02, atol=0.02).all(axis=1)
    return float(1.0 - ok.mean())


def make_env(cfg: EnvConfig, num_envs: int, seed: int, threads: int | None = None) -> EnvBundle:
    """Build the configured environment (`humanoid` or `toy`) with `num_envs` parallel copies, stepped on `threads`
    threads (None: all cores; data-parallel ranks on one machine share them). With `env.npmp`, the agent acts in
    that NPMP's latent space (`fbcpr.apps.npmp.reuse`)."""
    bundle = _toy(cfg, num_envs) if cfg.name == "toy" else _humanoid(cfg, num_envs, threads)
    if cfg.npmp is None:
        return bundle
    from fbcpr.apps.npmp.reuse import latent_bundle  # lazy: torch-heavy NPMP code only for runs that use it

    return latent_bundle(bundle, cfg)


def _toy(cfg: EnvConfig, num_envs: int) -> EnvBundle:
    from fbcpr.envs import toy as pm

    def task_reward(name: str) -> TaskReward:
        try:
            fn = pm.get_task(name)
        except KeyError as err:
            raise _task_error(err) from None
        return lambda next_obs, qpos, qvel: fn(next_obs)

    demos = pm.demo_paths()
    names = list(demos) if cfg.motions == "synthetic" else [n.strip() for n in cfg.motions.split(",")]
    unknown = [n for n in names if n not in demos]
    if unknown:
        raise ConfigError(f"env.motions: unknown toy demonstration {unknown[0]!r}; give 'synthetic' (all) or "
                          f"comma-separated names of {sorted(demos)}")
    lib = pm.DemoLibrary({n: demos[n] for n in names})
    init = pm.MixtureInit(cfg.fall_prob, lib)

    def pos_err(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.linalg.norm(a[:, :2] - b[:, :2], axis=-1)

    return EnvBundle(
        env=pm.PointMassVectorEnv(num_envs, init=init, max_episode_steps=cfg.max_episode_steps),
        library=lib, obs_dim=pm.OBS_DIM, action_dim=pm.ACTION_DIM, nq=pm.NQ, nv=pm.NV,
        make_eval_env=lambda n, steps: pm.PointMassVectorEnv(n, max_episode_steps=steps),
        clip_obs=lambda i: lib.clips[i],
        clip_start=lambda i: (lib.clips[i][0].astype(np.float64), np.zeros(pm.NV)),
        # mean position error in units of 0.1, so the paper's EMD bins [0.5, 5] span 0.05-0.5 of the arena
        emd=lambda a, b: float(10.0 * pos_err(a, b).mean()),
        success=lambda a, b: bool((pos_err(a, b) <= 0.1).all()),
        task_reward=task_reward,
    )


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


def _humanoid(cfg: EnvConfig, num_envs: int, threads: int | None = None) -> EnvBundle:
    from humanoid_env import NQ, NU, NV, OBS_DIM
    from humanoid_env.inits import make_init
    from humanoid_env.env import reset_fallen_steps
    from humanoid_env.vector import VectorHumanoidEnv
    from motions.library import MotionLibrary

    if cfg.motions == "synthetic":
        from motions.synthetic import default_library

        lib = default_library()
    else:
        path = Path(cfg.motions)
        if not path.exists():
            raise FileNotFoundError(f"env.motions: {path} does not exist (give a clip .npz, a folder of them or "
                                    "'synthetic')")
        lib = MotionLibrary.load([path] if path.is_file() else path)  # one clip: single-demonstration imitation
    from fbcpr.eval.metrics import emd, tracking_success

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


def tracking_latents(model: Any, obs_seq: np.ndarray, seq_length: int) -> torch.Tensor:
    """z_t ∝ sum_{j=t+1}^{t+L} B(s_j) for every t of a reference (T, obs_dim); the window shrinks at the end."""
    with torch.no_grad():
        b = model.backward(torch.as_tensor(obs_seq, dtype=torch.float32, device=model.device))
        return project_sphere(tracking_sums(b, seq_length))


def track_clips(model: Any, bundle: EnvBundle, clip_ids: list[int], seq_length: int, max_steps: int,
                stop: Callable[[], bool] = lambda: False) -> list[np.ndarray] | None:
    """Roll out the policy tracking each clip from its first frame (one env per clip, all in one batch).

    Returns the agent's observation trajectories, each as long as min(clip length, max_steps + 1), or None
    when `stop()` turns true (checked every step, so a Ctrl-C during training's tracking pass is answered
    within one env step rather than after all clips)."""
    refs = [bundle.clip_obs(i)[: max_steps + 1] for i in clip_ids]
    horizon = max(len(r) for r in refs) - 1
    zs = [tracking_latents(model, r, seq_length) for r in refs]
    z_all = torch.stack([torch.cat([z, z[-1:].expand(horizon + 1 - len(z), -1)]) for z in zs])  # (n, H+1, d)
    starts = [bundle.clip_start(i) for i in clip_ids]
    env = bundle.make_eval_env(len(clip_ids), horizon + 1)
    try:
        obs, _ = env.reset(seed=0, options={"qpos": np.stack([s[0] for s in starts]), "qvel": np.stack([s[1] for s in starts])})
        traj = [obs]
        for t in range(horizon):
            if stop():
                return None
            action = model.act(torch.as_tensor(obs, device=model.device), z_all[:, t], mean=True)
            obs, *_ , info = env.step(action.cpu().numpy())
            traj.append(info["final_obs"])
    finally:
        env.close()
    traj_arr = np.stack(traj, 1)
    return [traj_arr[k, : len(r)] for k, r in enumerate(refs)]


def tracking_scores(model: Any, bundle: EnvBundle, seq_length: int, max_clips: int, max_steps: int,
                    rng: np.random.Generator, stop: Callable[[], bool] = lambda: False,
                    shard: tuple[int, int] = (0, 1)) -> dict[str, tuple[float, bool]] | None:
    """{clip name: (EMD, success)} for up to max_clips clips (all of them when the library is small enough);
    None when `stop()` interrupted the rollout. shard = (rank, world size): track only every world-size-th of the
    chosen clips, from the rank-th (the same rng on every rank chooses the same clips)."""
    n = len(bundle.library.names)
    ids = list(range(n)) if n <= max_clips else sorted(rng.choice(n, size=max_clips, replace=False).tolist())
    ids = ids[shard[0]::shard[1]]
    if not ids:
        return {}
    trajs = track_clips(model, bundle, ids, seq_length, max_steps, stop)
    if trajs is None:
        return None
    out = {}
    for i, traj in zip(ids, trajs):
        ref = bundle.clip_obs(i)[: len(traj)]
        out[bundle.library.names[i]] = (bundle.emd(traj, ref), bundle.success(traj, ref))
    return out
