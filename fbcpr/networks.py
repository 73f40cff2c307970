"""Networks of FB-CPR (App. C.5, Tables 5-7) built from batched-ensemble layers.

Every layer holds the weights of all ensemble members in one tensor (members, in, out), so a single
`torch.baddbmm` serves the whole ensemble. Activations have shape (members, batch, features); a 2-D
input is shared by all members. Every `forward` takes `detach_params`: the actor loss evaluates F and Q
with frozen weights so its gradient reaches only the actor, with no extra backward pass.
"""
from __future__ import annotations

import math

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


class EnsembleLayerNorm(nn.Module):
    """LayerNorm with a separate affine transform per ensemble member."""

    def __init__(self, features: int, members: int = 1) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.ones(members, 1, features))
        self.bias = nn.Parameter(torch.zeros(members, 1, features))

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        w, b = (self.weight.detach(), self.bias.detach()) if detach_params else (self.weight, self.bias)
        return F.layer_norm(x, x.shape[-1:]) * w + b


class Stack(nn.Module):
    """Linear layers with the paper's activations: layernorm+tanh after the first, ReLU after the others.

    `final` is the activation after the last layer: "relu" (embeddings), or None (a linear output).
    """

    def __init__(self, sizes: list[int], members: int, final: str | None) -> None:
        super().__init__()
        self.layers = nn.ModuleList(EnsembleLinear(a, b, members) for a, b in zip(sizes[:-1], sizes[1:]))
        self.norm = EnsembleLayerNorm(sizes[1], members)
        self.final = final

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            x = layer(x, detach_params)
            if i == 0 and (i < last or self.final == "relu"):
                x = torch.tanh(self.norm(x, detach_params))
            elif i < last or self.final == "relu":
                x = F.relu(x)
        return x


def _embedding(in_dim: int, hidden: int, layers: int, members: int) -> Stack:
    """Embedding branch (Table 6): `layers` layers, the last one of width hidden/2."""
    return Stack([in_dim] + [hidden] * (layers - 1) + [hidden // 2], members, final="relu")


class ZConditionedNet(nn.Module):
    """Two-embedding architecture (Table 6): phi(s, x) and psi(s, z) concatenated, then an MLP.

    F and Q use x = a; the actor uses no x (an embedding over s alone). Output: (members, n, out_dim).
    """

    def __init__(self, obs_dim: int, extra_dim: int, z_dim: int, out_dim: int, hidden: int, hidden_layers: int,
                 embedding_layers: int, members: int) -> None:
        super().__init__()
        self.members = members
        self.embed_x = _embedding(obs_dim + extra_dim, hidden, embedding_layers, members)
        self.embed_z = _embedding(obs_dim + z_dim, hidden, embedding_layers, members)
        self.head = _Head(hidden // 2 * 2, hidden, hidden_layers, out_dim, members)

    def embed(self, obs: Tensor, z: Tensor, detach_params: bool = False) -> Tensor:
        """psi(s, z): shared by every evaluation at the same (s, z) (F loss and actor loss reuse it)."""
        return self.embed_z(torch.cat([obs, z], -1), detach_params)

    def forward(self, obs: Tensor, extra: Tensor | None, z: Tensor, detach_params: bool = False,
                z_embedding: Tensor | None = None) -> Tensor:
        ez = self.embed(obs, z, detach_params) if z_embedding is None else z_embedding
        x = obs if extra is None else torch.cat([obs, extra], -1)
        ex = self.embed_x(x, detach_params)
        if ex.shape[0] != ez.shape[0]:
            ez = ez.expand(ex.shape[0], -1, -1)
        return self.head(torch.cat([ex, ez], -1), detach_params)


class _Head(nn.Module):
    """Main MLP after the embeddings: `hidden_layers` ReLU layers then a linear output."""

    def __init__(self, in_dim: int, hidden: int, hidden_layers: int, out_dim: int, members: int) -> None:
        super().__init__()
        sizes = [in_dim] + [hidden] * hidden_layers + [out_dim]
        self.layers = nn.ModuleList(EnsembleLinear(a, b, members) for a, b in zip(sizes[:-1], sizes[1:]))

    def forward(self, x: Tensor, detach_params: bool = False) -> Tensor:
        for layer in self.layers[:-1]:
            x = F.relu(layer(x, detach_params))
        return self.layers[-1](x, detach_params)


class BackwardNet(nn.Module):
    """B(s) (Table 5, state embeddings): a simple MLP, output l2-normalised and scaled to sqrt(d)."""

    def __init__(self, obs_dim: int, z_dim: int, hidden: int, hidden_layers: int) -> None:
        super().__init__()
        self.z_dim = z_dim
        self.net = Stack([obs_dim] + [hidden] * hidden_layers + [z_dim], 1, final=None)

    def forward(self, obs: Tensor) -> Tensor:
        return project_sphere(self.net(obs)[0])


class Discriminator(nn.Module):
    """D(s, z) (Table 7): MLP over the concatenation; `logits` are log D - log(1 - D)."""

    def __init__(self, obs_dim: int, z_dim: int, hidden: int, hidden_layers: int) -> None:
        super().__init__()
        self.net = Stack([obs_dim + z_dim] + [hidden] * hidden_layers + [1], 1, final=None)

    def logits(self, obs: Tensor, z: Tensor) -> Tensor:
        return self.net(torch.cat([obs, z], -1))[0, :, 0]

    def forward(self, obs: Tensor, z: Tensor) -> Tensor:
        return torch.sigmoid(self.logits(obs, z))


def project_sphere(z: Tensor) -> Tensor:
    """Project onto the sphere of radius sqrt(d), the support of every z the policy sees."""
    return math.sqrt(z.shape[-1]) * F.normalize(z, dim=-1)
