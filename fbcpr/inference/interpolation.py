"""Weight-space interpolation of two FB-CPR models of one lineage: (1 - alpha) * base + alpha * tuned.

A run continued from a model (`--init-from`) can gain skills (balance under pushes, walking) and lose others
(some reward tasks). Averaging the weights of the two, tensor by tensor, often keeps most of both: Wortsman et al.
(2022, "Robust fine-tuning of zero-shot models", WiSE-FT) show this for a model and its fine-tuned copy, which
stay in one basin of the loss. It only makes sense for two checkpoints where one was trained on from the other;
two independent runs have unrelated weights and their average is noise.

A continuation's reward states are its own last replay states, and prompts inferred from them can be worse than
from its base's: an average of six continuations stood 5.5 s under the stand prompt with them and the whole 10 s
with the shipped model's. `with_reward_states` pairs one model's weights with the states of one or more
others.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Sequence

import numpy as np
import torch

from fbcpr.core.checkpoint import REWARD_KEYS, CheckpointError
from fbcpr.core.errors import InputError
from fbcpr.inference.bfm import BFM, check_compatible


def interpolate(base: BFM, tuned: BFM, alpha: float) -> BFM:
    """A new BFM whose every floating-point tensor (networks and observation normaliser) is
    `(1 - alpha) * base + alpha * tuned`; config and reward-inference buffer are `tuned`'s.

    Raises InputError for alpha outside [0, 1] and CheckpointError when the two models differ in architecture,
    env or action mapping (their weights would not mean the same thing)."""
    if not (isinstance(alpha, (int, float)) and math.isfinite(alpha) and 0.0 <= alpha <= 1.0):
        raise InputError(f"alpha: expected a number in [0, 1], got {alpha!r}")
    check_compatible(base, tuned, f"interpolate {base.source} and {tuned.source}", same_networks=True)
    sa, sb = base.model.state_dict(), tuned.model.state_dict()
    if sa.keys() != sb.keys() or any(sa[k].shape != sb[k].shape for k in sa):
        raise CheckpointError(f"cannot interpolate {base.source} and {tuned.source}: their tensors differ")
    model = copy.deepcopy(tuned.model)
    model.load_state_dict({k: torch.lerp(sa[k], sb[k], alpha) if sa[k].is_floating_point() else sb[k] for k in sa})
    return BFM(model, tuned.config, reward_buffer=tuned.reward_buffer,
               source=f"interpolate({base.source}, {tuned.source}, alpha={alpha:g})")


def with_reward_states(model: BFM, donors: Sequence[BFM]) -> BFM:
    """`model` with the reward-inference states of `donors`, all of them in one buffer, for prompts inferred from
    the states the donors' were (a later export can subsample it).

    Raises InputError for no donor, and CheckpointError when a donor differs from `model` in env, action mapping or
    z size, or has no states."""
    if not donors:
        raise InputError("with_reward_states: give at least one model to take the reward states of")
    given = []
    for donor in donors:
        check_compatible(model, donor, f"take the reward states of {donor.source} for {model.source}",
                         same_networks=False)
        states = donor.reward_buffer
        if states is None:
            raise CheckpointError(f"{donor.source} has no reward-inference states to give")
        given.append(states)
    buffer = {k: np.concatenate([np.asarray(s[k], np.float32) for s in given]) for k in REWARD_KEYS}
    names = " and ".join(str(d.source) for d in donors)
    return BFM(model.model, model.config, reward_buffer=buffer,
               source=f"{model.source} with the reward states of {names}")
