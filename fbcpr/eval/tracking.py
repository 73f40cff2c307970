"""Tracking clips with a latent-conditioned policy during training: z_t from the clip's next states, rolled out
on the bundle's evaluation env, scored by the env's own EMD and success (paper App. C.3)."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from fbcpr.core.protocols import EnvBundle
from fbcpr.eval.rollout import Step, rollout
from fbcpr.nn.latents import tracking_sums
from fbcpr.nn.networks import project_sphere


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
        obs, _ = env.reset(seed=0, options={"qpos": np.stack([s[0] for s in starts]),
                                            "qvel": np.stack([s[1] for s in starts])})
        traj = [obs]

        def act(t: int, o: np.ndarray) -> np.ndarray:
            return model.act(torch.as_tensor(o, device=model.device), z_all[:, t], mean=True).cpu().numpy()

        def watch(step: Step) -> bool:
            traj.append(step.info["final_obs"])
            return stop()

        if stop() or rollout(env, obs, act, horizon, watch) < horizon:
            return None
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
