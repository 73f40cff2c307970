"""Holding a continued run near the model it started from (`agent.anchor_actor`; not in the paper).

A run warm-started from a model (`--init-from`) learns new skills, such as balance under pushes, and loses prompt
quality. docs/results.md section 25 split that loss between the two halves of a continued model: the loaded
model's goal z's brought one continued actor back to the loaded model's goal success (hence `agent.freeze_backward`,
which holds B and the normaliser), while its tracking worsened with the actor itself. Tracking prompts the actor
with ER_FB latents of demonstration windows, so the anchor penalises the actor for moving its mean on demonstration
states under their own latents, and leaves it free elsewhere: on fall and push states, and under reward prompts.
"""
from __future__ import annotations

import copy

import torch
from torch import Tensor, nn

from fbcpr.fb_cpr.model import FBCPRModel


class ActorAnchor(nn.Module):
    """A frozen copy of an actor and of the normaliser it reads, taken from the model a run starts from."""

    def __init__(self, model: FBCPRModel) -> None:
        super().__init__()
        self.actor = copy.deepcopy(model.actor)
        self.obs_normalizer = copy.deepcopy(model.obs_normalizer)
        self.requires_grad_(False)

    @torch.no_grad()
    def hold(self, model: FBCPRModel) -> None:
        """Take the model's current actor and normaliser as the anchor (after a warm start loaded them)."""
        self.actor.load_state_dict(model.actor.state_dict())
        self.obs_normalizer.load_state_dict(model.obs_normalizer.state_dict())

    def gap(self, model: FBCPRModel, states: Tensor, states_n: Tensor, z: Tensor) -> Tensor:
        """Mean squared difference between the model's tanh action mean at (states, z) and the anchor's.

        states: raw observations (n, obs), which the anchor normalises with its own statistics; states_n: the same
        states under the model's normaliser; z: (n, d) latents."""
        with torch.no_grad():
            held = torch.tanh(self.actor(self.obs_normalizer(states), None, z)[0])
        return (model.actor_mean(states_n, z) - held).square().mean()
