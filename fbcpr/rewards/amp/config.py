"""The `agent.amp:` section: sizes and rate of the (s, s') discriminator."""
from __future__ import annotations

from dataclasses import dataclass

from fbcpr.core.schema import NON_NEGATIVE, POSITIVE, _f


@dataclass
class AMPConfig:
    """AMP/GAIfO discriminator (FB-CPR's discriminator sizes and rate, Table 7, by default)."""

    hidden_dim: int = _f(1024, POSITIVE)
    hidden_layers: int = _f(3, POSITIVE)
    lr: float = _f(1e-5, POSITIVE)
    grad_penalty: float = _f(10.0, NON_NEGATIVE)
