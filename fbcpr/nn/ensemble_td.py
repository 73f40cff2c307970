"""Ensemble critics' TD maths shared by every TD3-style learner (FB-CPR's F and Q, TD3's Q).

Shapes: m = ensemble size, n = batch size. `discount` is the per-sample gamma * (1 - terminated).
"""
from __future__ import annotations

import torch
from torch import Tensor


def pessimistic(values: Tensor, coef: float) -> Tensor:
    """Ensemble reduction of C.5.2: mean minus coef * mean pairwise |difference| over dim 0.

    coef = 0 gives the mean; for two members coef = 0.5 gives their minimum.
    """
    m = values.shape[0]
    mean = values.mean(0)
    if coef == 0.0 or m == 1:
        return mean
    if m == 2:  # the paper's ensembles: the mean pairwise |difference| is |v_0 - v_1|, in 3 kernels instead of 6
        return torch.sub(mean, (values[0] - values[1]).abs(), alpha=coef)
    spread = (values.unsqueeze(0) - values.unsqueeze(1)).abs().sum((0, 1)) / (m * (m - 1))
    return mean - coef * spread


def td_loss(values: Tensor, reward: Tensor, target: Tensor, discount: Tensor) -> Tensor:
    """Sum over members of mean_i (v_k,i - r_i - discount_i * target_i)^2 (Algorithm 1 lines 25, 29). values: (m, n)."""
    return (values - (reward + discount * target)).square().mean(-1).sum()


def action_penalty(action: Tensor, value_scale: Tensor, coef: float) -> Tensor:
    """coef * stopgrad(value_scale) * mean(action^2): a pull of the policy toward action 0.

    Not in the paper. Q grows toward the box edges where data is thin, and the actor turns bang-bang within a few
    thousand updates; under the `rest` action mapping action 0 is the standing pose, so this pull is a prior
    toward standing. Scaling by the value magnitude keeps `coef` meaningful as Q drifts.
    """
    return coef * value_scale.detach() * action.square().mean()


def behaviour_cloning(action: Tensor, target: Tensor, rows: Tensor, value_scale: Tensor, coef: float) -> Tensor:
    """coef * stopgrad(value_scale) * mean over the marked rows of mean((action - target)^2): TD3+BC's pull of the
    policy toward demonstrated actions, scaled like `action_penalty` so that the two weights compare."""
    per_row = (action - target).square().mean(-1)
    return coef * value_scale.detach() * (per_row * rows).sum() / rows.sum().clamp(min=1)
