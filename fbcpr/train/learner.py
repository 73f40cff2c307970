"""The learner: draws update batches (replay transitions and demonstration windows) and runs `agent.update` on
them, as many as the config's update-to-data ratio owes for the env steps collected.

The ratio is `train.updates_per_rollout` updates per `train.rollout_steps` env steps, whatever engine collects
them, so a run means the same on a machine with 2 cores and on one with 16.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from fbcpr.core.protocols import EnvBundle, OnlineAgent
from fbcpr.core.schema import Config, batch_config
from fbcpr.nn.distributed import Replicas
from fbcpr.train.buffer import ReplayBuffer
from fbcpr.train.device_batches import DeviceBatches


class Learner:
    """Updates `agent` from `buffer` (or its device copy `batches`) and the library's windows."""

    def __init__(self, cfg: Config, agent: OnlineAgent, bundle: EnvBundle, buffer: ReplayBuffer,
                 batches: DeviceBatches | None, rng: np.random.Generator, replicas: Replicas) -> None:
        self.cfg, self.agent, self.bundle, self.buffer, self.batches = cfg, agent, bundle, buffer, batches
        self.rng, self.replicas = rng, replicas
        self.updates = 0
        self.last_metrics: Mapping[str, float] = {}  # the last update's, read lazily (fbcpr.nn.lazy_metrics)
        self.demos: dict[str, torch.Tensor] | None = None  # train.demonstration_share: the demonstrations held apart

    def sample_batch(self) -> tuple[dict[str, Any], torch.Tensor]:
        """One update's draw, as training takes it: a replay batch and expert windows of the motion library."""
        a = batch_config(self.cfg.agent)
        clips = getattr(self.agent, "window_clips", False)  # agents that treat some clips' windows apart
        if self.batches is not None:
            batch, windows = self.batches.sample(a.batch_size, a.batch_size // a.seq_length, a.seq_length, clips)
        else:
            batch = self.buffer.sample(self.rng, a.batch_size, fields=self.agent.fields,
                                       history=getattr(self.agent, "history", 0),  # states before obs: sequence rewards
                                       frames=getattr(self.agent, "frame_size", 0) > 0)  # and their frames (video)
            library, w = self.bundle.library, a.batch_size // a.seq_length
            if clips:
                frames, clip = library.sample_window_clips(self.rng, w, a.seq_length)
                batch["window_clip"] = torch.as_tensor(clip)
            else:
                frames = library.sample_windows(self.rng, w, a.seq_length)
            windows = torch.as_tensor(frames)
        if self.demos is not None:
            batch = self._with_demonstrations(batch)
        return batch, windows

    def _with_demonstrations(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """train.demonstration_share: the batch's first rows drawn (with replacement) from the demonstrations held
        apart; "demo" marks them, "demo_next" those whose demonstration goes on, with its next action in
        "demo_next_action", and "demo_target" holds their behaviour-cloning targets (zeros elsewhere)."""
        demos = self.demos
        assert demos is not None  # held apart whenever train.demonstration_share is set
        size = len(batch["obs"])
        k = round(self.cfg.train.demonstration_share * size)
        idx = torch.as_tensor(self.rng.integers(0, len(demos["obs"]), size=k), device=batch["obs"].device)
        out = dict(batch)
        for key, rows in demos.items():
            rest = batch[key][k:] if key in batch else rows.new_zeros((size - k, *rows.shape[1:]))
            out[key] = torch.cat([rows[idx].to(rest.dtype), rest])
        return out

    def update(self) -> None:
        """One update on a fresh draw (under torchrun: the replicas kept identical, `fbcpr.nn.distributed`)."""
        batch, windows = self.sample_batch()
        with self.replicas.synchronized():
            self.last_metrics = self.agent.update(batch, windows)
        self.updates += 1


def updates_owed(cfg: Config, env_steps_since: int, done_since: int) -> int:
    """Updates the ratio owes after `env_steps_since` env steps collected since updates began, `done_since` of them
    done: updates_per_rollout for every whole rollout_steps."""
    tc = cfg.train
    return max(0, env_steps_since // tc.rollout_steps * tc.updates_per_rollout - done_since)
