"""The `agent.near:` section: the energy network, its offline denoising-score-matching training, the noise ladder,
the annealing rule and the reward transform. Defaults are the paper's (App. B.2, Table 4) where it gives one."""
from __future__ import annotations

from dataclasses import dataclass

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import POSITIVE, _check, _f

_INT_AT_LEAST_2 = _check(lambda v: v >= 2, "must be >= 2")


@dataclass
class NEARConfig:
    """Energy e(x) over normalised (s, s' - s), e(x, sigma) = e(x) / sigma, sigma on a geometric ladder
    sigma_max = sigma_1 > ... > sigma_L = sigma_min."""

    hidden_dim: int = _f(512, POSITIVE)
    hidden_layers: int = _f(3, POSITIVE)
    sigma_max: float = _f(20.0, POSITIVE)
    sigma_min: float = _f(0.01, POSITIVE)
    num_levels: int = _f(50, _INT_AT_LEAST_2)
    pretrain_steps: int = _f(100_000, POSITIVE)   # the paper runs 0.8e5-1.5e5 (Table 5); configs for CPU set fewer
    batch_size: int = _f(128, POSITIVE)
    lr: float = _f(1e-5, POSITIVE)
    ema: float = _f(0.999, _check(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)"))
    grad_clip: float = _f(1.0, POSITIVE)
    dataset_size: int = _f(20_000, POSITIVE)       # transitions drawn from the demonstrations: the set M of Alg. 1
    anneal: bool = _f(True)
    anneal_threshold: float = _f(0.2, POSITIVE)    # alpha of Algorithm 1 (the paper gives no value)
    transform: bool = _f(True)
    transform_scale: float = _f(10.0, POSITIVE)    # tanh((r - r') / 10), Section 5.1
    transform_history: int = _f(3, POSITIVE)       # r' = mean of the last k rollout phases' mean reward (k = 3)

    def validate(self, prefix: str) -> None:
        if self.sigma_min >= self.sigma_max:
            raise ConfigError(f"{prefix}.sigma_min: must be < sigma_max ({self.sigma_max:g}), got {self.sigma_min:g}")
