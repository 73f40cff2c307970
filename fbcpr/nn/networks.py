"""Networks of FB-CPR (App. C.5, Tables 5-7) built from batched-ensemble layers.

Every layer holds the weights of all ensemble members in one tensor (members, in, out), so a single
`torch.baddbmm` serves the whole ensemble. Activations have shape (members, batch, features); a 2-D
input is shared by all members. Every `forward` takes `detach_params`: the actor loss evaluates F and Q
with frozen weights so its gradient reaches only the actor, with no extra backward pass.
"""
from __future__ import annotations

import math
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class EnsembleLinear(nn.Module):
    """`members` independent affine maps applied with one batched matmul."""

    def __init__(self, in_features: int, out_features: int, members: int = 1) -> None:
        super().__init__()
        self.in_features, self.out_features, self.members = in_features, out_features, members
        self.weight = nn.Parameter(torch.empty(members, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(members, 1, out_features))
        bound = 1.0 / math.sqrt(in_features)  # nn.Linear's default init, per member
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        w, b = (self.weight.detach(), self.bias.detach()) if detach_params else (self.weight, self.bias)
        if x.dim() == 2:  # input shared by all members: a stride-0 view, no copy
            x = x.expand(self.members, -1, -1)
        return torch.baddbmm(b, x, w)

    def partial(self, x: Tensor, start: int, stop: int, detach_params: bool = False, bias: bool = True,
                add_to: Tensor | None = None) -> Tensor:
        """Contribution of input features [start, stop) (x holds just those), plus the bias and/or `add_to`."""
        w = self.weight[:, start:stop]
        w = w.detach() if detach_params else w
        if x.dim() == 2:
            x = x.expand(self.members, -1, -1)
        if add_to is None:
            base = (self.bias.detach() if detach_params else self.bias) if bias else None
            return torch.bmm(x, w) if base is None else torch.baddbmm(base, x, w)
        if bias:
            add_to = add_to + (self.bias.detach() if detach_params else self.bias)
        return torch.baddbmm(add_to, x, w)


class EnsembleLayerNorm(nn.Module):
    """LayerNorm with a separate affine transform per ensemble member."""

    def __init__(self, features: int, members: int = 1) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(members, 1, features))
        self.bias = nn.Parameter(torch.zeros(members, 1, features))

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        w, b = (self.weight.detach(), self.bias.detach()) if detach_params else (self.weight, self.bias)
        if w.shape[0] == 1:  # one member: layer_norm's own affine, one kernel each way instead of four
            return F.layer_norm(x, x.shape[-1:], w.view(-1), b.view(-1))
        return torch.addcmul(b, F.layer_norm(x, x.shape[-1:]), w)


class Stack(nn.Module):
    """Linear layers with the paper's activations: layernorm+tanh after the first, ReLU after the others.

    `final` is the activation after the last layer: "relu" (embeddings), or None (a linear output).
    """

    def __init__(self, sizes: list[int], members: int, final: str | None) -> None:
        super().__init__()
        self.layers = nn.ModuleList(EnsembleLinear(a, b, members) for a, b in zip(sizes[:-1], sizes[1:]))
        self.norm = EnsembleLayerNorm(sizes[1], members)
        self.final = final

    @property
    def first(self) -> EnsembleLinear:
        """The first layer, whose input blocks `ZConditionedNet` evaluates separately."""
        return cast(EnsembleLinear, self.layers[0])

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        return self.forward_from(self.layers[0](x, detach_params), detach_params)

    def forward_from(self, x: Tensor, detach_params: bool = False) -> Tensor:
        """Continue from the first layer's pre-activation."""
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            if i > 0:
                x = layer(x, detach_params)
            if i == 0 and (i < last or self.final == "relu"):
                x = torch.tanh(self.norm(x, detach_params))
            elif i < last or self.final == "relu":
                x = F.relu(x, inplace=True)  # x is a fresh matmul output that nothing else saved
        return x


def _embedding(in_dim: int, hidden: int, layers: int, members: int) -> Stack:
    """Embedding branch (Table 6): `layers` layers, the last one of width hidden/2."""
    return Stack([in_dim] + [hidden] * (layers - 1) + [hidden // 2], members, final="relu")


class ZConditionedNet(nn.Module):
    """Two-embedding architecture (Table 6): phi(s, x) and psi(s, z) concatenated, then an MLP.

    F and Q use x = a; the actor uses no x (an embedding over s alone). Output: (members, n, out_dim).
    Concatenations feeding a linear layer are computed as sums of per-block matmuls, so the blocks that
    depend only on (s, z) (`precompute`) can be shared by several evaluations that differ only in the action.
    """

    def __init__(self, obs_dim: int, extra_dim: int, z_dim: int, out_dim: int, hidden: int, hidden_layers: int,
                 embedding_layers: int, members: int) -> None:
        super().__init__()
        self.members, self.obs_dim, self.embed_width = members, obs_dim, hidden // 2
        self.embed_x = _embedding(obs_dim + extra_dim, hidden, embedding_layers, members)
        self.embed_z = _embedding(obs_dim + z_dim, hidden, embedding_layers, members)
        self.head = _Head(hidden // 2 * 2, hidden, hidden_layers, out_dim, members)

    def precompute(self, obs: Tensor, z: Tensor, detach_params: bool = False) -> tuple[Tensor, Tensor]:
        """The (s, z)-only parts: phi's first-layer pre-activation from s, and psi(s, z)'s contribution to the
        head's first layer. Reusable for any action at the same (s, z)."""
        ez = self.embed_z(torch.cat([obs, z], -1), detach_params)
        x_pre = self.embed_x.first.partial(obs, 0, self.obs_dim, detach_params, bias=True)
        z_pre = self.head.first.partial(ez, self.embed_width, 2 * self.embed_width, detach_params, bias=True)
        return x_pre, z_pre

    def forward(self, obs: Tensor, extra: Tensor | None, z: Tensor, detach_params: bool = False,
                pre: tuple[Tensor, Tensor] | None = None) -> Tensor:
        x_pre, z_pre = self.precompute(obs, z, detach_params) if pre is None else pre
        first = self.embed_x.first
        if extra is not None:
            x_pre = first.partial(extra, self.obs_dim, first.in_features, detach_params, bias=False, add_to=x_pre)
        ex = self.embed_x.forward_from(x_pre, detach_params)
        h = self.head.first.partial(ex, 0, self.embed_width, detach_params, bias=False, add_to=z_pre)
        return self.head.forward_from(h, detach_params)


class _Head(nn.Module):
    """Main MLP after the embeddings: `hidden_layers` ReLU layers then a linear output."""

    def __init__(self, in_dim: int, hidden: int, hidden_layers: int, out_dim: int, members: int) -> None:
        super().__init__()
        sizes = [in_dim] + [hidden] * hidden_layers + [out_dim]
        self.layers = nn.ModuleList(EnsembleLinear(a, b, members) for a, b in zip(sizes[:-1], sizes[1:]))

    @property
    def first(self) -> EnsembleLinear:
        """The first layer, whose input blocks `ZConditionedNet` evaluates separately."""
        return cast(EnsembleLinear, self.layers[0])

    def forward_from(self, h: Tensor, detach_params: bool = False) -> Tensor:
        """Continue from the first layer's pre-activation."""
        for layer in self.layers[1:]:
            h = layer(F.relu(h, inplace=True), detach_params)
        return h


class BackwardNet(nn.Module):
    """B(s) (Table 5, state embeddings): a simple MLP, output l2-normalised and scaled to sqrt(d).

    B always runs in float32, bf16 autocast or not: the implicit reward solves with Sigma_B = E[B B^T], which is
    ill-conditioned early in training, and B's bf16 rounding then moved FB-CPR's Fz loss by 22% at paper-S. B is
    the smallest network, so float32 costs little."""

    def __init__(self, obs_dim: int, z_dim: int, hidden: int, hidden_layers: int) -> None:
        super().__init__()
        self.z_dim = z_dim
        self.net = Stack([obs_dim] + [hidden] * hidden_layers + [z_dim], 1, final=None)

    def forward(self, obs: Tensor) -> Tensor:
        with torch.autocast(obs.device.type, enabled=False):
            return project_sphere(self.net(obs.float())[0])


class Discriminator(nn.Module):
    """D(s, z) (Table 7): MLP over the concatenation; `logits` are log D - log(1 - D)."""

    def __init__(self, obs_dim: int, z_dim: int, hidden: int, hidden_layers: int) -> None:
        super().__init__()
        self.net = Stack([obs_dim + z_dim] + [hidden] * hidden_layers + [1], 1, final=None)

    def logits(self, obs: Tensor, z: Tensor) -> Tensor:
        return self.net(torch.cat([obs, z], -1))[0, :, 0]

    def forward(self, obs: Tensor, z: Tensor) -> Tensor:
        return torch.sigmoid(self.logits(obs, z))


def noisy_action(mean: Tensor, std: float, clip: float, generator: torch.Generator | None = None,
                 noise: Tensor | None = None) -> Tensor:
    """mean + N(0, std^2) noise clipped to [-clip, clip], clamped to [-1, 1] with a straight-through gradient.

    TD3's exploration and target-policy smoothing, used by every actor (FB-CPR's pi(s, z), TD3's pi(s)). `noise`:
    standard normal draws of mean's shape made beforehand (a compiled update traces no generator), else drawn here."""
    if noise is None:
        noise = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
    noise = noise.to(mean.dtype)
    a = mean + (noise * std).clamp(-clip, clip)
    return a + (a.clamp(-1.0, 1.0) - a).detach()


def project_sphere(z: Tensor) -> Tensor:
    """Project onto the sphere of radius sqrt(d), the support of every z the policy sees."""
    return math.sqrt(z.shape[-1]) * F.normalize(z, dim=-1)
