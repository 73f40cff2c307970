"""The `agent.virl:` section: comparator sizes, loss and reward weights (paper Eq. 4 and App. 7.7), data sources."""
from __future__ import annotations

from dataclasses import dataclass

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import NON_NEGATIVE, POSITIVE, _check, _f

INPUTS = ("state", "video")


@dataclass
class VIRLConfig:
    """Recurrent Siamese comparator (VIRL). Loss weights default to the paper's λ = (0.7, 0.1, 0.1, 0.1)."""

    input: str = _f("state", _check(lambda v: v in INPUTS, f"must be one of {INPUTS}"))
    seq_length: int = _f(8, _check(lambda v: 2 <= v <= 64, "must be in [2, 64]"))  # frames per compared sequence
    motion: bool = _f(True)                              # each frame also carries its change from the previous one
    embed_dim: int = _f(64, POSITIVE)
    hidden_dim: int = _f(128, POSITIVE)                  # frame MLP width and GRU width
    image_size: int = _f(64, _check(lambda v: v >= 8 and v % 4 == 0, "must be a multiple of 4, >= 8"))
    margin: float = _f(1.0, POSITIVE)                    # ρ of the contrastive loss (Eq. 3)
    noise: float = _f(0.05, NON_NEGATIVE)                # σ of the noisy positive copies (normalised units / pixels)
    lr: float = _f(3e-4, POSITIVE)
    seq_loss_weight: float = _f(0.7, NON_NEGATIVE)       # λ1: sequence Siamese loss
    frame_loss_weight: float = _f(0.1, NON_NEGATIVE)     # λ2: frame Siamese loss
    seq_ae_weight: float = _f(0.1, NON_NEGATIVE)         # λ3: recurrent (sequence) autoencoder
    frame_ae_weight: float = _f(0.1, NON_NEGATIVE)       # λ4: frame autoencoder
    seq_reward_weight: float = _f(1.0, NON_NEGATIVE)     # distance = seq * ||h_e - h_a|| + frame * ||e_e - e_a||
    frame_reward_weight: float = _f(1.0, NON_NEGATIVE)
    reward_width: float = _f(1.0, POSITIVE)              # reward = exp(-width * distance^2) (App. 7.7 uses 5)
    bank_size: int = _f(256, POSITIVE)                   # demonstration windows the reward aligns against
    multitask: str | None = _f(None, path="humanoid")  # other clips for the comparator only (names / a folder)
    demo_frames: str | None = _f(None, path="any")  # video demo: a folder of frames instead of the env's demo

    def validate(self, prefix: str) -> None:
        if self.seq_reward_weight + self.frame_reward_weight <= 0:
            raise ConfigError(f"{prefix}.seq_reward_weight: it or frame_reward_weight must be > 0")
        if self.seq_loss_weight + self.frame_loss_weight <= 0:
            raise ConfigError(f"{prefix}.seq_loss_weight: it or frame_loss_weight must be > 0 (no contrastive loss)")
        if self.demo_frames is not None and self.input != "video":
            raise ConfigError(f"{prefix}.demo_frames: a folder of frames needs input: video")
