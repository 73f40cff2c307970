"""Algorithm 1's annealing: which noise level's energy is the reward, moved on the agent's imitation progress.

Start at sigma_1 (the largest). After each rollout phase, progress = e(A, sigma_k) / e_ref - 1, where e(A, sigma_k)
is the mean energy of the phase's online transitions A and e_ref the mean energy of the first phase after the
switch to sigma_k. progress > alpha: switch to sigma_{k+1} (smaller, sharper); progress < -alpha: back to
sigma_{k-1}. Written as (e - e_ref) / |e_ref|, which is the same for e_ref > 0 and still reads "improved" as
positive when the energies are negative (ours are anchored so the demonstrations' mean energy is 0).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class Annealer:
    """Level index k (0-based: 0 = sigma_1) and the reference energy of the current level (None: not yet taken)."""

    num_levels: int
    threshold: float
    level: int = 0
    reference: float | None = None

    def step(self, mean_energy: float) -> float:
        """Take one phase's mean energy at the current level; move the level per Algorithm 1; return the progress
        (0.0 for the phase that sets the reference)."""
        if self.reference is None:
            self.reference = mean_energy
            return 0.0
        progress = (mean_energy - self.reference) / max(abs(self.reference), 1e-8)
        if progress > self.threshold and self.level < self.num_levels - 1:
            self.level, self.reference = self.level + 1, None
        elif progress < -self.threshold and self.level > 0:
            self.level, self.reference = self.level - 1, None
        return progress

    def state(self) -> dict[str, Any]:
        return {"level": self.level, "reference": self.reference}

    def load_state(self, meta: dict[str, Any]) -> None:
        self.level, self.reference = int(meta["level"]), meta["reference"]
