"""NPMP hyperparameters (paper App. B and Sections 2-3), validated like the run config: a bad key or value is a
`ConfigError` naming `npmp.<key>`. `preset` picks a size: `paper` (the defaults) or `cpu` (minutes on 2 cores)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import POSITIVE, _build, _check, _f, _range


@dataclass
class NPMPConfig:
    """Sizes, prior and objective of the motor-primitive model, and its optimiser."""

    latent_dim: int = _f(60, _range(1, 4096))
    horizon: int = _f(5, _range(1, 100))                   # K future frames the encoder sees
    alpha: float = _f(0.95, _check(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)"))  # AR(1) prior; 0: i.i.d.
    beta: float = _f(0.1, _check(lambda v: v >= 0.0, "must be >= 0"))
    encoder_hidden: int = _f(1024, _range(1, 16384))
    encoder_layers: int = _f(2, _range(1, 16))
    decoder_hidden: int = _f(1024, _range(1, 16384))
    decoder_layers: int = _f(3, _range(1, 16))
    action_std: float = _f(0.1, POSITIVE)                  # fixed std of the decoder's Gaussian
    seq_length: int = _f(30, _range(1, 10_000))            # subsequence length of a training sample
    batch_size: int = _f(512, _range(1, 1 << 16))          # subsequences per gradient step
    lr: float = _f(1e-4, POSITIVE)
    seed: int = _f(0, _range(0, 2**31 - 1))


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "cpu": dict(encoder_hidden=256, decoder_hidden=256, seq_length=8, batch_size=64, lr=3e-4),
    "tiny": dict(latent_dim=4, horizon=2, encoder_hidden=16, encoder_layers=1, decoder_hidden=16, decoder_layers=1,
                 seq_length=4, batch_size=4, lr=1e-3),
}


def npmp_config(data: dict[str, Any] | None = None, preset: str | None = None) -> NPMPConfig:
    """An NPMPConfig from a preset name and overrides (as a checkpoint's JSON holds them)."""
    data = dict(data or {})
    name = data.pop("preset", None) if preset is None else preset
    if name is not None:
        if name not in PRESETS:
            raise ConfigError(f"npmp.preset: unknown preset {name!r}; choose from {sorted(PRESETS)}")
        data = {**PRESETS[name], **data}
    return _build(NPMPConfig, data, "npmp")
