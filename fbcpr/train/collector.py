"""The collector: steps the training envs with the agent's exploration and writes every transition into the replay
buffer (and its device copy), in the trainer's process (`train.engine: sync`, the default).

It owns what a rollout carries from one step to the next: the envs' observations, each env's rollout latent z and
its age (a new one every `train.z_update_every` steps and at every new episode), the episodes finished and the
statistics of the policy's actions. `fbcpr.train.workers` runs the same steps in worker processes instead.
For an agent with a video reward (`frame_size` > 0) it renders each transition's s' once, as a grey frame the buffer
keeps (`fbcpr.rewards.virl.frames.HumanoidFrames`): updates read stored frames and never render.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fbcpr.core.protocols import EnvBundle, OnlineAgent
from fbcpr.core.schema import Config, batch_config
from fbcpr.rewards.virl.frames import HumanoidFrames
from fbcpr.train.buffer import ReplayBuffer
from fbcpr.train.device_batches import DeviceBatches

#: |action| beyond which a component counts as saturated (at a joint limit's side of the PD range).
SATURATED = 0.9


def rollout_latents(agent: OnlineAgent, library: Any, online: np.ndarray | torch.Tensor | None,
                    rng: np.random.Generator, n: int, seq_length: int) -> torch.Tensor:
    """n rollout latents from the agent (FB-CPR's nu) given online next states (or None) and demonstration windows
    drawn from `library`."""
    windows = torch.as_tensor(library.sample_windows(rng, n, seq_length))
    return agent.rollout_z(n, None if online is None else torch.as_tensor(online), windows)


def buffer_latents(cfg: Config, agent: OnlineAgent, library: Any, buffer: ReplayBuffer, rng: np.random.Generator,
                   n: int) -> torch.Tensor:
    """n rollout latents, online states drawn from the replay buffer (once it holds any)."""
    online = buffer.sample(rng, n, fields=("next_obs",))["next_obs"] if len(buffer) else None
    return rollout_latents(agent, library, online, rng, n, batch_config(cfg.agent).seq_length)


def action_stats(action: np.ndarray) -> np.ndarray:
    """(sum |a|, saturated components, components) of a batch of policy actions."""
    mag = np.abs(action)
    return np.array([mag.sum(), (mag > SATURATED).sum(), mag.size], dtype=np.float64)


class Collector:
    """Steps `bundle.env` (all of the run's envs on this process) one vector step at a time."""

    def __init__(self, cfg: Config, bundle: EnvBundle, agent: OnlineAgent, buffer: ReplayBuffer,
                 batches: DeviceBatches | None, rng: np.random.Generator, device: torch.device, seed: int) -> None:
        self.cfg, self.bundle, self.agent, self.buffer, self.batches = cfg, bundle, agent, buffer, batches
        self.rng, self.device = rng, device
        self.random_steps = 0  # vector steps of uniform random actions still to take (the trainer sets the warm-up)
        self.episodes = 0
        self.stats = np.zeros(3)  # sum |a|, saturated components, components (policy actions only)
        self.obs, _ = bundle.env.reset(seed=seed)
        self.z = self.sample_z(cfg.train.num_envs)
        self.z_age = np.zeros(cfg.train.num_envs, dtype=np.int64)
        size = getattr(agent, "frame_size", 0)
        self.frames = HumanoidFrames(size) if size else None

    def sample_z(self, n: int) -> torch.Tensor:
        """n rollout latents, online states drawn from the replay buffer (once it holds any)."""
        return buffer_latents(self.cfg, self.agent, self.bundle.library, self.buffer, self.rng, n)

    def step(self) -> int:
        """One vector step (uniform random actions while `random_steps` last, else the policy); returns the
        transitions it added to the buffer's count (num_envs, dropped ones included)."""
        tc, agent = self.cfg.train, self.agent
        n = tc.num_envs
        stale = np.flatnonzero(self.z_age >= tc.z_update_every)
        if len(stale):
            self.z[torch.as_tensor(stale, device=self.device)] = self.sample_z(len(stale))
            self.z_age[stale] = 0
        if self.random_steps > 0:
            self.random_steps -= 1
            action = self.rng.uniform(-1.0, 1.0, size=(n, self.bundle.action_dim)).astype(np.float32)
        else:
            action = agent.act(torch.as_tensor(self.obs, device=self.device), self.z).cpu().numpy()
            self.stats += action_stats(action)
        next_obs, _, terminated, truncated, info = self.bundle.env.step(action)
        transition = {"obs": self.obs, "action": action, "next_obs": info["final_obs"], "z": self.z.cpu().numpy(),
                      "qpos": info["final_qpos"], "qvel": info["final_qvel"], "terminated": terminated}
        if self.frames is not None:
            transition["frame"] = self.frames.render(info["final_qpos"])
        rows = self.buffer.add(transition)
        if self.batches is not None:
            self.batches.added(rows)
        if hasattr(agent, "observe"):  # agents that track their own progress (NEAR's annealing, in TD3 or FB-CPR)
            agent.observe(torch.as_tensor(self.obs), torch.as_tensor(info["final_obs"]), self.z)
        done = np.asarray(terminated | truncated)
        self.obs = next_obs
        self.z_age += 1
        self.z_age[done] = tc.z_update_every  # a new episode gets a new z
        self.episodes += int(done.sum())
        return n

    def sync_policy(self) -> None:
        """Nothing to hand over: this collector acts with the learner's own model."""

    def take_stats(self) -> np.ndarray:
        """The action statistics since the last call (then reset)."""
        out = self.stats.copy()
        self.stats[:] = 0
        return out

    def state(self) -> dict[str, torch.Tensor]:
        """The rollout's state for a checkpoint: the envs' whole state (a resume steps exactly as this run would
        have), their observations, latents and latent ages."""
        env = self.bundle.env
        qpos, qvel, episode_steps = env.get_state()
        tensors = {f"env_state.{k}": torch.as_tensor(v) for k, v in env.save_state().items()}
        tensors.update({"env_qpos": torch.as_tensor(qpos), "env_qvel": torch.as_tensor(qvel),
                        "env_obs": torch.as_tensor(self.obs), "z": self.z.cpu(), "z_age": torch.as_tensor(self.z_age),
                        "env_episode_steps": torch.as_tensor(episode_steps)})
        return tensors

    def load_state(self, tensors: dict[str, torch.Tensor]) -> None:
        """Put back what `state` gave (ValueError from the env when its state does not fit this env); checkpoints
        from before the whole env state was saved give qpos and qvel, close but not bit-exact."""
        env = self.bundle.env
        self.z = tensors["z"].to(self.device)
        self.z_age = tensors["z_age"].numpy().copy()
        env_state = {k.removeprefix("env_state."): v.numpy() for k, v in tensors.items() if k.startswith("env_state.")}
        if env_state:
            env.load_state(env_state)
            self.obs = tensors["env_obs"].numpy().copy()
        else:
            self.obs, _ = env.reset(options={"qpos": tensors["env_qpos"].numpy(), "qvel": tensors["env_qvel"].numpy()})
            env.set_episode_steps(tensors["env_episode_steps"].numpy())

    def restart(self, seed: int) -> None:
        """New episodes and latents for every env (a resumed rank other than 0, seeded apart)."""
        self.episodes = 0
        self.obs, _ = self.bundle.env.reset(seed=seed)
        self.z = self.sample_z(self.cfg.train.num_envs)
        self.z_age = np.zeros(self.cfg.train.num_envs, dtype=np.int64)
