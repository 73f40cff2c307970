"""The z-inference maths of App. C.5.3 on B values, shared by the prompts (`fbcpr.inference.prompt`) and training-time
evaluation (`fbcpr.envs.bundle`, `fbcpr.eval.toy`), which must not load a checkpoint or a BFM just to do it.

Both return unprojected sums: callers project onto the sqrt(d) sphere with their own projection, which makes
any positive scale (a mean instead of a sum, a softmax instead of raw exponentials) irrelevant.
"""
from __future__ import annotations

import torch

#: τ of the weighted reward regression z ∝ Σ exp(τ r(s)) r(s) B(s).
TEMPERATURE = 10.0


def reward_weights(r: torch.Tensor, temperature: float | None = TEMPERATURE) -> torch.Tensor:
    """(N,) weights w with z ∝ Σ_i w_i B(s_i) for rewards r (N,) of the states s_i.

    Weighted regression: w = r·exp(τ(r − max r)) (the exp(τ·max r) factor only rescales z, and subtracting it
    keeps exp from overflowing); temperature None: the plain FB regression w = r / N.
    """
    if temperature is None:
        return r / r.shape[0]
    return torch.exp(temperature * (r - r.max())) * r


def tracking_sums(b: torch.Tensor, seq_length: int) -> torch.Tensor:
    """(T, d) Σ_{j=t+1}^{t+L} B(s_j) for every step t of a reference whose states give b = B(s_0..s_{T-1}) (T, d).

    The window of the next L states shrinks at the end of the reference; the last step, with no state after
    it, keeps B(s_{T-1}) as its target, so a rollout can run one step past the reference's last transition.
    """
    csum = torch.cat([torch.zeros_like(b[:1]), b.cumsum(0)])  # csum[k] = Σ_{j<k} b_j
    T = b.shape[0]
    t = torch.arange(T, device=b.device)
    hi = torch.clamp(t + seq_length + 1, max=T)
    lo = torch.clamp(t + 1, max=T - 1)
    return csum[hi] - csum[lo]
