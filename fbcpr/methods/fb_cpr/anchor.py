"""Holding a continued run near the model it started from (`agent.anchor_actor`; not in the paper).

A run warm-started from a model (`--init-from`) learns new skills, such as balance under pushes, and loses prompt
quality. That loss splits between the two halves of a continued model: the loaded model's goal z's brought one
continued actor back to the loaded model's goal success (hence `agent.freeze_backward`, which holds B and the
normaliser), while its tracking worsened with the actor itself. Tracking prompts the actor with ER_FB latents of
demonstration windows, so the anchor penalises the actor for moving its mean on demonstration states under their own
latents, and leaves it free elsewhere: on fall and push states, and under reward prompts. The reward tasks were then
what a held run still lost, so `agent.anchor_rewards` names reward tasks whose prompts the anchor holds too: the
batch's states under each task's z as a reward prompt of the loaded model gives it: its stored prompt where it has
one (refined at export, possibly), else inferred once, through the frozen B, from its reward-inference sample. A
run that adds demonstrations of a new skill names their clips in `agent.anchor_free`: the anchor leaves their
windows free, or it would hold the actor at the loaded model's behaviour on the very states the run is to teach.
"""
from __future__ import annotations

import copy
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import TaskReward
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.nn.latents import reward_weights
from fbcpr.nn.networks import project_sphere


class ActorAnchor(nn.Module):
    """A frozen copy of an actor and of the normaliser it reads, taken from the model a run starts from, and the z's
    of the reward prompts it holds (`prompts`, (tasks, d); absent when it holds none)."""

    prompts: Tensor | None

    def __init__(self, model: FBCPRModel, reward_tasks: int = 0) -> None:
        super().__init__()
        self.actor = copy.deepcopy(model.actor)
        self.obs_normalizer = copy.deepcopy(model.obs_normalizer)
        self.register_buffer("prompts", torch.zeros(reward_tasks, model.z_dim) if reward_tasks else None)
        self.requires_grad_(False)

    @torch.no_grad()
    def hold(self, model: FBCPRModel) -> None:
        """Take the model's current actor and normaliser as the anchor (after a warm start loaded them)."""
        self.actor.load_state_dict(model.actor.state_dict())
        self.obs_normalizer.load_state_dict(model.obs_normalizer.state_dict())

    def gap(self, model: FBCPRModel, states: Tensor, states_n: Tensor, z: Tensor, weight: Tensor | None = None
            ) -> Tensor:
        """Mean squared difference between the model's tanh action mean at (states, z) and the anchor's.

        states: raw observations (n, obs), which the anchor normalises with its own statistics; states_n: the same
        states under the model's normaliser; z: (n, d) latents; weight: (n,) 1 for the states held, 0 for those
        left free (the mean is over the held ones; 0 when none is)."""
        with torch.no_grad():
            held = torch.tanh(self.actor(self.obs_normalizer(states), None, z)[0])
        sq = (model.actor_mean(states_n, z) - held).square()
        if weight is None:
            return sq.mean()
        return (sq.mean(-1) * weight).sum() / weight.sum().clamp_min(1.0)


def free_clips(library: Any, patterns: list[str]) -> np.ndarray:
    """(clips,) bool: the clips of a motion library whose windows the anchor leaves free (`agent.anchor_free`).
    Every pattern must name some clip, and some clip must stay held."""
    names = list(library.names)
    matched = [library.matching([p]) for p in patterns]
    unmatched = [p for p, m in zip(patterns, matched) if not m.any()]
    if unmatched:
        raise ConfigError(f"agent.anchor_free: {unmatched[0]!r} matches no clip of env.motions "
                          f"({len(names)} clips, e.g. {names[:3]})")
    free = np.any(matched, axis=0)
    if free.all():
        raise ConfigError(f"agent.anchor_free: {patterns} match all {len(names)} clips, so the anchor would hold "
                          "nothing; set agent.anchor_actor: 0 instead")
    return free


@torch.no_grad()
def reward_prompts(model: FBCPRModel, sample: dict[str, np.ndarray], rewards: dict[str, TaskReward]) -> Tensor:
    """(tasks, d): the weighted-regression z of each reward over a reward-inference sample (next_obs, qpos, qvel),
    on the sqrt(d) sphere, as `fbcpr.inference.prompt.Prompt.reward` infers it from a checkpoint with this sample."""
    b = model.backward_map(model.normalize(torch.as_tensor(sample["next_obs"], dtype=torch.float32,
                                                           device=model.device))).double()
    zs = []
    for name, fn in rewards.items():
        r = torch.as_tensor(np.asarray(fn(sample["next_obs"], sample["qpos"], sample["qvel"]), dtype=np.float64),
                            device=b.device)
        w = reward_weights(r)
        if not torch.all(torch.isfinite(w)) or not torch.any(w != 0):
            raise ConfigError(f"agent.anchor_rewards: {name!r} is zero or non-finite on all {r.shape[0]} states of the "
                              "loaded reward-inference sample, so it has no z to hold")
        zs.append(w @ b)
    return project_sphere(torch.stack(zs)).float()
