"""VIRL's training signal (paper Eq. 3-4, App. 7.9): labelled pairs of sequences and the losses on them.

Positive pairs (y = 1): a demonstration window and a noisy copy of it, the window with a frame duplicated, two
windows of the demonstration, two windows of the same other clip (multi-task data). Not two windows of the agent
(the paper's adversarial positives): with one demonstration they pulled every agent window to one point, away from
the demo, and the reward went flat (the same for every behaviour of the agent; on the toy, DTW no better than random).
Negative pairs (y = 0): the window and its reversal, a time-shuffle, one of its frames held for the whole window,
the window and an agent rollout window, the window and another clip's, and windows of two different other clips.
Frame-level pairs only where time step t of both sides should (not) match: the noisy copy (positive), agent and
other clips (negative); time manipulations keep the frames, so they say nothing about single frames.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from fbcpr.rewards.virl.model import Comparator, distance


@dataclass
class Pairs:
    """All sequences to encode once (K, L, *frame), the pairs as index columns, and their labels."""

    seqs: Tensor
    left: Tensor          # (P,) long
    right: Tensor         # (P,) long
    label: Tensor         # (P,) 1 positive, 0 negative
    frame_label: Tensor   # (P,) 1 / 0 for frame-level pairs, -1 where the frame term does not apply
    base: int             # seqs[:base] are unaugmented (demo, agent, other clips): the autoencoders' data


def contrastive(d: Tensor, y: Tensor, margin: float) -> Tensor:
    """Eq. 3: y * d + (1 - y) * max(margin - d, 0), elementwise."""
    return y * d + (1 - y) * F.relu(margin - d)


def balanced_mean(loss: Tensor, y: Tensor) -> Tensor:
    """Mean over positives and over negatives, averaged: the paper's half-positive, half-negative batches."""
    pos, neg = y > 0.5, y < 0.5
    return 0.5 * (loss[pos].mean() + loss[neg].mean())


def make_pairs(expert: Tensor, agent: Tensor, others: Tensor | None, other_ids: Tensor | None, noise: float,
               generator: torch.Generator) -> Pairs:
    """Pairs from n demonstration windows, n agent windows and optional other-clip windows (all (n, L, *frame))."""
    n, steps, dev = expert.shape[0], expert.shape[1], expert.device
    rand = lambda *shape: torch.rand(*shape, generator=generator, device=dev)  # noqa: E731
    ar = torch.arange(n, device=dev)
    noisy = expert + noise * torch.randn(expert.shape, generator=generator, device=dev)
    dup = expert.clone()
    t = 1 + (rand(n) * (steps - 1)).long()
    dup[ar, t] = expert[ar, t - 1]
    reversed_ = expert.flip(1)
    shuffled = expert[ar[:, None], rand(n, steps).argsort(1)]
    frozen = expert[ar, (rand(n) * steps).long()][:, None].expand_as(expert)
    roll = (ar + 1 + (rand(1) * max(n - 1, 1)).long()) % n            # another window of the same source
    parts = [expert, agent] + ([others] if others is not None else []) + [noisy, dup, reversed_, shuffled, frozen]
    seqs = torch.cat(parts)
    base = sum(p.shape[0] for p in parts[:-5])
    E, A, aug = 0, n, base                                            # offsets of the blocks in seqs
    left, right, label, frame = [], [], [], []

    def add(lo: Tensor, ro: Tensor, y: float | Tensor, f: float | Tensor) -> None:
        left.append(lo)
        right.append(ro)
        label.append(torch.as_tensor(y, device=dev, dtype=torch.float32).expand(len(lo)))
        frame.append(torch.as_tensor(f, device=dev, dtype=torch.float32).expand(len(lo)))

    add(E + ar, aug + ar, 1.0, 1.0)                                    # noisy copy
    add(E + ar, aug + n + ar, 1.0, -1.0)                               # a frame duplicated
    add(E + ar, E + roll, 1.0, -1.0)                                   # two demonstration windows
    add(E + ar, aug + 2 * n + ar, 0.0, -1.0)                           # reversed
    add(E + ar, aug + 3 * n + ar, 0.0, -1.0)                           # shuffled
    add(E + ar, aug + 4 * n + ar, 0.0, -1.0)                           # one frame held
    add(E + ar, A + ar, 0.0, 0.0)                                      # demonstration vs agent
    if others is not None and other_ids is not None:
        k, O = others.shape[0], 2 * n
        ok = torch.arange(k, device=dev)
        mate = (ok + 1 + (rand(1) * max(k - 1, 1)).long()) % k
        same = (other_ids == other_ids[mate]).float()
        add(O + ok, O + mate, same, torch.where(same > 0, -1.0, 0.0))  # same clip: positive; different: negative
        m = min(n, k)
        add(E + ar[:m], O + ok[:m], 0.0, 0.0)                          # demonstration vs other clips
    return Pairs(seqs, torch.cat(left), torch.cat(right), torch.cat(label), torch.cat(frame), base)


def virl_loss(model: Comparator, pairs: Pairs, margin: float, weights: tuple[float, float, float, float]
              ) -> tuple[Tensor, dict[str, Tensor]]:
    """Eq. 4: λ1 sequence Siamese + λ2 frame Siamese + λ3 recurrent AE + λ4 frame AE (plain AEs: no KL term)."""
    e, h = model.encode(pairs.seqs)
    y = pairs.label
    d_seq = distance(h[pairs.left], h[pairs.right])
    seq = balanced_mean(contrastive(d_seq, y, margin), y)
    fmask = pairs.frame_label >= 0
    fy = pairs.frame_label[fmask][:, None].expand(-1, e.shape[1])
    d_frame = distance(e[pairs.left[fmask]], e[pairs.right[fmask]])
    frame = balanced_mean(contrastive(d_frame, fy, margin), fy)
    x, eb, hb = pairs.seqs[:pairs.base], e[:pairs.base], h[:pairs.base]
    frame_ae = F.mse_loss(model.decode_frames(eb), x)
    seq_ae = F.mse_loss(model.decode_sequence(hb, x.shape[1]), x.flip(1))
    w1, w2, w3, w4 = weights
    total = w1 * seq + w2 * frame + w3 * seq_ae + w4 * frame_ae
    pos = y > 0.5
    return total, {"seq_loss": seq, "frame_loss": frame, "seq_ae": seq_ae, "frame_ae": frame_ae,
                   "d_pos": d_seq[pos].mean(), "d_neg": d_seq[~pos].mean()}
