"""The recurrent Siamese comparator: frame encoder/decoder (MLP for states, small conv net for grey frames) and a
GRU sequence encoder/decoder (paper Fig. 1a, App. Fig. 9 at smaller width). Both sides of a pair share weights."""
from __future__ import annotations

import torch
from torch import Tensor, nn

from fbcpr.rewards.virl.config import VIRLConfig


def _mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def conv_encoder(channels: int, size: int, hidden: int, embed: int) -> nn.Sequential:
    """Paper App. Fig. 9's conv net: 8 filters 6x6 stride 2, 16 filters 4x4 stride 2, then two dense layers."""
    side = size // 4
    return nn.Sequential(nn.Conv2d(channels, 8, 6, 2, 2), nn.ReLU(), nn.Conv2d(8, 16, 4, 2, 1), nn.ReLU(), nn.Flatten(),
                         nn.Linear(16 * side * side, hidden), nn.ReLU(), nn.Linear(hidden, embed))


def conv_decoder(channels: int, size: int, hidden: int, embed: int) -> nn.Sequential:
    """The encoder in reverse, with transposed convolutions (linear output: motion channels are signed)."""
    side = size // 4
    return nn.Sequential(nn.Linear(embed, hidden), nn.ReLU(), nn.Linear(hidden, 16 * side * side), nn.ReLU(),
                         nn.Unflatten(1, (16, side, side)), nn.ConvTranspose2d(16, 8, 4, 2, 1), nn.ReLU(),
                         nn.ConvTranspose2d(8, channels, 6, 2, 2))


def distance(a: Tensor, b: Tensor) -> Tensor:
    """Euclidean distance over the last dim (zero gradient at zero, so identical pairs are safe)."""
    return torch.linalg.vector_norm(a - b, dim=-1)


class Comparator(nn.Module):
    """e_t = frame encoder(o_t); h = Linear(GRU(e_0..e_t)); decoders rebuild frames from e and the reversed
    sequence from h. Inputs: states (N, L, obs_dim), or frames (N, L, 1, S, S) when cfg.input == "video"; with
    cfg.motion each frame also carries its change from the previous one (2 * obs_dim features, 2 channels)."""

    def __init__(self, obs_dim: int, cfg: VIRLConfig) -> None:
        super().__init__()
        width = 2 if cfg.motion else 1
        h, d = cfg.hidden_dim, cfg.embed_dim
        if cfg.input == "video":
            self.frame_shape: tuple[int, ...] = (width, cfg.image_size, cfg.image_size)
            self.frame_encoder = conv_encoder(width, cfg.image_size, h, d)
            self.frame_decoder = conv_decoder(width, cfg.image_size, h, d)
        else:
            self.frame_shape = (width * obs_dim,)
            self.frame_encoder = _mlp([width * obs_dim, h, h, d])
            self.frame_decoder = _mlp([d, h, h, width * obs_dim])
        self.seq_encoder = nn.GRU(d, h, batch_first=True)
        self.seq_head = nn.Linear(h, d)
        self.seq_decoder = nn.GRU(d, h, batch_first=True)
        self.seq_out = nn.Linear(h, d)

    def frames(self, x: Tensor) -> Tensor:
        """Frame embeddings e: (N, L, *frame) -> (N, L, embed)."""
        n, steps = x.shape[:2]
        return self.frame_encoder(x.reshape(n * steps, *self.frame_shape)).view(n, steps, -1)

    def encode(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """(e (N, L, embed), h (N, embed)): frame embeddings and the sequence embedding after the last frame."""
        e = self.frames(x)
        _, last = self.seq_encoder(e)
        return e, self.seq_head(last[0])

    def decode_frames(self, e: Tensor) -> Tensor:
        """Frames (N, L, *frame) rebuilt from their embeddings (the frame autoencoder)."""
        n, steps = e.shape[:2]
        out = self.frame_decoder(e.reshape(n * steps, -1))
        return out.view(n, steps, *self.frame_shape)

    def decode_sequence(self, h: Tensor, steps: int) -> Tensor:
        """The sequence rebuilt from h, last frame first (the recurrent autoencoder decodes in inverse order)."""
        out, _ = self.seq_decoder(h[:, None].expand(-1, steps, -1).contiguous())
        return self.decode_frames(self.seq_out(out))
