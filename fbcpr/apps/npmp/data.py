"""Expert data for NPMP distillation, collected from any `BFM` tracking clips, in one safetensors format.

- BC from noisy rollouts (paper Sec. 2.3): the expert tracks each clip `rollouts` times with Gaussian action noise;
  the first rollout starts at frame 0, the others at random frames, so a weak expert that falls early still covers
  the clip. Logged: visited state s_t and the intended (noise-free) expert action mu_E(s_t).
- LFPC (Sec. 2.3, Eq. 6-9): one noise-free nominal rollout per clip, logging also J_t = d mu_E / d s at s*_t,
  computed by autograd through the BFM actor (torch.func.jacrev, vmapped over states); training then draws
  perturbed states s* + ds with targets a* + J ds. Jacobians are stored as float16 (they dominate the size).

Every episode also records which clip and clip frame it started at (the reference it tracked). Files carry
their format and version in the safetensors header; `load` checks keys, shapes, dtypes and values and never
unpickles. `max_bytes` bounds a dataset before any simulation runs.
"""
from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import Tensor

from fbcpr.core.errors import FBCPRError

FORMAT, VERSION = "fbcpr-npmp-data", 1
METHODS = ("bc", "lfpc")
MAX_BYTES = 1 << 30
_JAC_CHUNK = 64


class DataError(FBCPRError, ValueError):
    """An expert dataset that is missing, malformed, too large or inconsistent; the message names the file/key."""


@dataclass
class ExpertData:
    """Episodes of (state, intended expert action) pairs, flat with offsets; Jacobians for LFPC."""

    method: str
    obs: Tensor                 # (N, obs_dim) float32 visited states
    action: Tensor              # (N, action_dim) float32 intended expert actions mu_E(s)
    episode_start: Tensor       # (E + 1,) int64 offsets into obs: episode e is rows [start[e], start[e+1])
    episode_clip: Tensor        # (E,) int64 index into clip_names
    episode_frame: Tensor       # (E,) int64 clip frame the episode started at
    clip_names: list[str]
    perturb_std: Tensor         # (obs_dim,) float32 std of LFPC state perturbations (zeros for BC)
    jacobian: Tensor | None = None  # (N, action_dim, obs_dim) float16, LFPC only
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def lengths(self) -> Tensor:
        return self.episode_start[1:] - self.episode_start[:-1]

    def save(self, path: str | Path) -> Path:
        """Write atomically (temporary file, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tensors = {"obs": self.obs, "action": self.action, "episode_start": self.episode_start,
                   "episode_clip": self.episode_clip, "episode_frame": self.episode_frame,
                   "perturb_std": self.perturb_std}
        if self.jacobian is not None:
            tensors["jacobian"] = self.jacobian
        header = {"format": FORMAT, "version": str(VERSION), "method": self.method,
                  "clip_names": json.dumps(self.clip_names), "meta": json.dumps(self.meta)}
        tmp = path.with_name(f".{path.name}.tmp")
        save_file({k: v.contiguous() for k, v in tensors.items()}, str(tmp), metadata=header)
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> ExpertData:
        """Read and validate a dataset file; DataError naming the file and the problem otherwise."""
        path = Path(path)
        if not path.is_file():
            raise DataError(f"{path}: no such expert-data file")
        try:
            with safe_open(str(path), framework="pt") as f:
                header = f.metadata() or {}
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as err:  # safetensors raises several types on malformed files
            raise DataError(f"{path}: not a readable safetensors file ({err})") from None
        if header.get("format") != FORMAT or header.get("version") != str(VERSION):
            raise DataError(f"{path}: not an NPMP expert dataset (format {header.get('format')!r}, version "
                            f"{header.get('version')!r}; expected {FORMAT!r} version {VERSION})")
        missing = [k for k in ("obs", "action", "episode_start", "episode_clip", "episode_frame", "perturb_std")
                   if k not in tensors]
        if missing:
            raise DataError(f"{path}: missing tensor {missing[0]!r}")
        try:
            names, meta = json.loads(header.get("clip_names", "")), json.loads(header.get("meta", "{}"))
        except json.JSONDecodeError as err:
            raise DataError(f"{path}: bad JSON in the header ({err})") from None
        if not (isinstance(names, list) and all(isinstance(n, str) for n in names)) or not isinstance(meta, dict):
            raise DataError(f"{path}: header clip_names must be a list of names and meta a mapping")
        try:
            return cls(method=header.get("method", ""), clip_names=names, meta=meta, jacobian=tensors.get("jacobian"),
                       **{k: tensors[k] for k in ("obs", "action", "episode_start", "episode_clip", "episode_frame",
                                                  "perturb_std")})
        except DataError as err:
            raise DataError(f"{path}: {err}") from None


def _validate(d: ExpertData) -> None:
    if d.method not in METHODS:
        raise DataError(f"method must be one of {METHODS}, got {d.method!r}")
    if d.obs.dim() != 2 or d.action.dim() != 2 or len(d.obs) != len(d.action) or len(d.obs) == 0:
        raise DataError(f"obs and action must be (N, obs_dim) and (N, action_dim) with N > 0, got "
                        f"{tuple(d.obs.shape)} and {tuple(d.action.shape)}")
    for name in ("obs", "action", "perturb_std"):
        t = getattr(d, name)
        if t.dtype != torch.float32:
            raise DataError(f"{name}: expected float32, got {t.dtype}")
        if not bool(torch.isfinite(t).all()):
            raise DataError(f"{name}: contains NaN or inf")
    if d.perturb_std.shape != (d.obs.shape[1],) or bool((d.perturb_std < 0).any()):
        raise DataError(f"perturb_std: expected ({d.obs.shape[1]},) values >= 0, got {tuple(d.perturb_std.shape)}")
    start, n_ep = d.episode_start, len(d.episode_clip)
    for name in ("episode_start", "episode_clip", "episode_frame"):
        if getattr(d, name).dtype != torch.int64 or getattr(d, name).dim() != 1:
            raise DataError(f"{name}: expected a 1-D int64 tensor")
    if n_ep == 0 or len(start) != n_ep + 1 or len(d.episode_frame) != n_ep:
        raise DataError(f"episode_start must hold E + 1 offsets for E = {n_ep} episodes (>= 1), got {len(start)}")
    if int(start[0]) != 0 or int(start[-1]) != len(d.obs) or bool((start[1:] <= start[:-1]).any()):
        raise DataError(f"episode_start must rise strictly from 0 to N = {len(d.obs)}")
    if (bool((d.episode_clip < 0).any()) or bool((d.episode_clip >= len(d.clip_names)).any())
            or bool((d.episode_frame < 0).any())):
        raise DataError(f"episode_clip must index the {len(d.clip_names)} clip names and episode_frame be >= 0")
    if d.method == "lfpc":
        want = (len(d.obs), d.action.shape[1], d.obs.shape[1])
        if d.jacobian is None or tuple(d.jacobian.shape) != want:
            got = None if d.jacobian is None else tuple(d.jacobian.shape)
            raise DataError(f"jacobian: LFPC data needs Jacobians of shape {want}, got {got}")
        if not bool(torch.isfinite(d.jacobian).all()):
            raise DataError("jacobian: contains NaN or inf")


def dataset_bytes(n_states: int, obs_dim: int, action_dim: int, lfpc: bool) -> int:
    """Bytes a dataset of n_states rows takes (float32 states and actions, float16 Jacobians)."""
    return n_states * (4 * (obs_dim + action_dim) + (2 * obs_dim * action_dim if lfpc else 0))


def expert_jacobian(bfm: Any, obs: Tensor, z: Tensor) -> Tensor:
    """(N, action_dim, obs_dim) d mu_E / d s of the BFM's mean action at raw states obs (N, obs_dim), latents z."""
    from torch.func import jacrev, vmap

    model = bfm.model

    def mean_action(o: Tensor, zz: Tensor) -> Tensor:
        return model.actor_mean(model.normalize(o[None]), zz[None])[0]

    jac = vmap(jacrev(mean_action), in_dims=(0, 0))
    return torch.cat([jac(obs[i:i + _JAC_CHUNK], z[i:i + _JAC_CHUNK]).detach() for i in range(0, len(obs), _JAC_CHUNK)])


def _episodes(library: Any, method: str, rollouts: int, max_steps: int,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(clip, start frame, steps) of every episode: rollout 0 of a clip from frame 0, others from random frames."""
    clips, frames = [], []
    for c, clip in enumerate(library.clips):
        if clip.n_frames < 2:
            raise DataError(f"clip {clip.name!r}: has {clip.n_frames} frame, tracking needs at least 2")
        for r in range(1 if method == "lfpc" else rollouts):
            clips.append(c)
            frames.append(0 if r == 0 else int(rng.integers(0, clip.n_frames - 1)))
    clip_idx, frame_idx = np.array(clips), np.array(frames)
    steps = np.minimum([library.clips[c].n_frames - 1 - f for c, f in zip(clips, frames)], max_steps)
    return clip_idx, frame_idx, steps.astype(np.int64)


def collect(bfm: Any, library: Any, method: str = "bc", rollouts: int = 10, noise: float = 0.1,
            max_steps: int = 300, perturb_scale: float = 0.1, seed: int = 0, max_bytes: int = MAX_BYTES,
            on_step: Callable[[int, int], None] | None = None,
            make_env: Callable[[int, int], Any] | None = None) -> ExpertData:
    """Roll the expert out on every clip of `library` (all episodes as one batch of envs) and log its data.

    method "bc": `rollouts` noisy rollouts per clip (noise: std of the Gaussian action noise, actions in [-1, 1]);
    "lfpc": one noise-free rollout per clip plus Jacobians, and perturbations of std perturb_scale x the
    per-dimension std of the logged states. Episodes last to the clip's end, at most max_steps steps, and stop
    early where the simulation diverges. on_step(done, total) reports progress. Clips offer n_frames, name and
    per-frame qpos/qvel (`motions.Clip`); make_env(num_envs, max_episode_steps) builds the batched env (default: the
    humanoid's, with the expert's action mapping; `fbcpr.envs.bundle.EnvBundle.make_eval_env` fits)."""

    if method not in METHODS:
        raise DataError(f"method: must be one of {METHODS}, got {method!r}")
    if rollouts < 1 or max_steps < 1 or noise < 0 or perturb_scale < 0:
        raise DataError(f"rollouts and max_steps must be >= 1, noise and perturb_scale >= 0; got {rollouts}, "
                        f"{max_steps}, {noise}, {perturb_scale}")
    rng = np.random.default_rng(seed)
    clip_idx, frame_idx, steps = _episodes(library, method, rollouts, max_steps, rng)
    size = dataset_bytes(int((steps + 1).sum()), bfm.obs_dim, bfm.action_dim, method == "lfpc")
    if size > max_bytes:
        raise DataError(f"the dataset would take {size / 2**20:,.0f} MiB, over the {max_bytes / 2**20:,.0f} MiB limit: "
                        "lower --max-steps or --rollouts (or raise --max-mb)")
    track = [bfm.prompt.track(clip) for clip in library.clips]  # (T-1, d) per clip
    horizon = int(steps.max())
    t_all = np.arange(horizon + 1)
    z = np.stack([track[c][np.minimum(f + t_all, len(track[c]) - 1)] for c, f in zip(clip_idx, frame_idx)])
    starts = [library.clips[c] for c in clip_idx]
    if make_env is None:
        from humanoid_env.vector import VectorHumanoidEnv

        env = VectorHumanoidEnv(len(clip_idx), max_episode_steps=horizon + 1, action_mapping=bfm.action_mapping)
    else:
        env = make_env(len(clip_idx), horizon + 1)
    obs_log = np.empty((len(clip_idx), horizon + 1, bfm.obs_dim), np.float32)
    act_log = np.empty((len(clip_idx), horizon + 1, bfm.action_dim), np.float32)
    ends = steps.copy()
    try:
        obs, _ = env.reset(seed=seed, options={"qpos": np.stack([c.qpos[f] for c, f in zip(starts, frame_idx)]),
                                               "qvel": np.stack([c.qvel[f] for c, f in zip(starts, frame_idx)])})
        for t in range(horizon + 1):
            mu = np.asarray(bfm.act(obs, z[:, t]), np.float32)
            obs_log[:, t], act_log[:, t] = obs, mu
            if t == horizon:
                break
            noisy = np.clip(mu + noise * rng.standard_normal(mu.shape), -1.0, 1.0) if method == "bc" else mu
            _, _, _, _, info = env.step(noisy.astype(np.float32))
            obs = info["final_obs"]
            diverged = info.get("diverged", np.zeros(len(ends), bool))
            ends = np.where(diverged & (ends > t), t, ends)  # the state before divergence is the last
            if on_step is not None:
                on_step(t + 1, horizon)
    finally:
        env.close()
    keep = t_all[None, :] <= ends[:, None]  # (E, H+1) rows of each episode, in episode order
    obs_t, act_t = torch.as_tensor(obs_log[keep]), torch.as_tensor(act_log[keep])
    offsets = torch.as_tensor(np.concatenate([[0], np.cumsum(ends + 1)]), dtype=torch.int64)
    jac, perturb = None, torch.zeros(bfm.obs_dim)
    if method == "lfpc":
        jac = expert_jacobian(bfm, obs_t, torch.as_tensor(z[keep])).to(torch.float16)
        perturb = (perturb_scale * obs_t.std(0)).float()
    meta = {"expert": str(getattr(bfm, "source", None) or "unknown"), "action_mapping": bfm.action_mapping,
            "rollouts": 1 if method == "lfpc" else rollouts, "noise": noise if method == "bc" else 0.0,
            "max_steps": max_steps, "perturb_scale": perturb_scale if method == "lfpc" else 0.0, "seed": seed}
    return ExpertData(method=method, obs=obs_t, action=act_t, episode_start=offsets,
                      episode_clip=torch.as_tensor(clip_idx, dtype=torch.int64),
                      episode_frame=torch.as_tensor(frame_idx, dtype=torch.int64),
                      clip_names=list(library.names), perturb_std=perturb, jacobian=jac, meta=meta)
