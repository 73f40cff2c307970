"""Prompt refinement: a zero-shot z improved by a few batches of rollouts, the weights untouched.

A reward or goal prompt is inferred from data (`fbcpr.inference.prompt`). When the user can afford a few minutes of
simulation, the same policy often does better under a nearby z: the fast-adaptation results on BFMs (search in
the latent space with the frozen policy, 10-40% over zero-shot in a few dozen episodes) are the model here. We
search with the cross-entropy method on the sqrt(d) sphere:

- each generation rolls out `population` z's (the current mean plus Gaussian perturbations, projected) from the
  same `starts` (common random numbers), all as one batch of envs;
- the mean moves to the projected mean of the `elites` best, and the step size shrinks by `decay`;
- the returned z is the best-scoring mean seen, z0 included, so the result never scores below z0 on the starts.

Scores are the mean per-step objective over the episode and the starts. A goal pose is turned into the objective
exp(-d_smpl / β) (β = the success threshold), which is positive, smooth, and largest at the pose.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import torch

from fbcpr.core.errors import PromptError
from fbcpr.inference.reward_spec import RewardSpec, reward_fn
from fbcpr.nn.networks import project_sphere

#: The most envs one generation may step at once (population x starts): ~0.1 MB of simulation state each.
MAX_ENVS = 4096
#: (next_obs (N, 358), qpos (N, 76), qvel (N, 75)) -> (N,) per-step value to maximise.
Objective = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


class Policy(Protocol):
    """What refinement needs of a model: a z-conditioned policy and the env's action mapping."""

    @property
    def z_dim(self) -> int: ...

    @property
    def action_mapping(self) -> str: ...

    def act(self, obs: np.ndarray, z: np.ndarray, mean: bool = True) -> Any: ...


@dataclass
class Search:
    """The cross-entropy method's settings (defaults: ~3 minutes for a 300-step reward on 2 CPU cores)."""

    generations: int = 10
    population: int = 16
    elites: int | None = None  # None: the best quarter of the population (at least one)
    sigma: float = 0.3
    decay: float = 0.9
    seed: int = 0

    def __post_init__(self) -> None:
        if self.elites is None and isinstance(self.population, (int, np.integer)):
            self.elites = max(1, int(self.population) // 4)

    @property
    def n_elites(self) -> int:
        """`elites` as resolved by `__post_init__` (an int once `check` has passed)."""
        assert self.elites is not None, "refine: elites unresolved; a Search with an integer population sets it"
        return self.elites

    def check(self) -> None:
        """Every setting in range, named when not."""
        for name in ("generations", "population", "elites"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise PromptError(f"refine: {name} must be a positive integer, got {value!r}")
        if self.population < 2:
            raise PromptError(f"refine: population must be at least 2 (the mean and one perturbation), "
                              f"got {self.population}")
        if self.n_elites > self.population:
            raise PromptError(f"refine: elites ({self.elites}) cannot exceed population ({self.population})")
        for name in ("sigma", "decay"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise PromptError(f"refine: {name} must be a finite number > 0, got {value!r}")


@dataclass
class Refined:
    """The refined z, where it started, and each generation's figures (for a curve or a table)."""

    z: np.ndarray
    z0: np.ndarray
    score: float
    score0: float
    episodes: int
    history: list[dict[str, float]] = field(default_factory=list)

    @property
    def cosine(self) -> float:
        """cos(z, z0): how far the search moved."""
        return float(self.z @ self.z0 / (np.linalg.norm(self.z) * np.linalg.norm(self.z0)))


def project(z: np.ndarray) -> np.ndarray:
    """Rows onto the sqrt(d) sphere the policy was trained on (float64 for the search's own arithmetic)."""
    z = np.asarray(z, dtype=np.float64)
    norm = np.linalg.norm(z, axis=-1)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0):
        raise PromptError("refine: a z that is zero or not finite cannot be projected onto the sphere")
    return project_sphere(torch.as_tensor(z)).numpy()


def cross_entropy(score: Callable[[np.ndarray], np.ndarray], z0: np.ndarray, search: Search | None = None,
                  on_generation: Callable[[dict[str, float]], None] | None = None) -> Refined:
    """Maximise score((K, d) z's) -> (K,) over the sphere from z0; row 0 of every batch is the current mean."""
    search = search or Search()
    search.check()
    z0 = np.asarray(z0, dtype=np.float64)
    if z0.ndim != 1 or not np.all(np.isfinite(z0)):
        raise PromptError(f"refine: z0 must be one finite vector (d,), got shape {z0.shape}")
    z0 = project(z0)
    d = z0.shape[0]
    rng = np.random.default_rng(search.seed)
    mean, sigma = z0, float(search.sigma)
    best_z, best, first = z0, -np.inf, np.nan
    history: list[dict[str, float]] = []
    for g in range(search.generations + 1):
        last = g == search.generations
        k = 1 if last else search.population  # the last round only scores the final mean
        cands = mean[None] if last else np.concatenate(
            [mean[None], project(mean[None] + sigma * rng.standard_normal((k - 1, d)))])
        scores = np.asarray(score(cands), dtype=np.float64)
        if scores.shape != (k,) or not np.all(np.isfinite(scores)):
            raise PromptError(f"refine: the score must be {k} finite values, got {scores}")
        if g == 0:
            first = float(scores[0])
        if scores[0] > best:
            best_z, best = mean, float(scores[0])
        row = {"generation": float(g), "mean_score": float(scores[0]), "best_score": float(scores.max()),
               "sigma": sigma, "cosine_z0": float(mean @ z0 / d)}
        history.append(row)
        if on_generation is not None:
            on_generation(row)
        if not last:
            elite = cands[np.argsort(scores)[-search.n_elites:]]
            mean, sigma = project(elite.mean(0)[None])[0], sigma * search.decay
    return Refined(z=best_z.astype(np.float32), z0=z0.astype(np.float32), score=best, score0=first,
                   episodes=0, history=history)


def standing_starts(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(qpos, qvel) of n standing starts (the env's default init) drawn with `seed`: where z's are rolled out."""
    from humanoid_env.inits import DefaultInit

    if n < 1:
        raise PromptError(f"refine: starts must be >= 1, got {n}")
    return DefaultInit().sample(np.random.default_rng(seed), n)


def rollout_score(policy: Policy, objective: Objective, starts: tuple[np.ndarray, np.ndarray], steps: int,
                  num_threads: int | None = None, on_step: Callable[[int], None] | None = None
                  ) -> Callable[[np.ndarray], np.ndarray]:
    """score(zs (K, d)) -> (K,): each z rolled out from every start (one batch of K x S envs, the evaluation
    runner's rollouts), the mean per-step objective over steps and starts; an env whose simulation diverges
    scores 0 for the rest of its episode. `on_step(K)` is called after every batched step (for a progress bar
    counting candidate-steps)."""
    from fbcpr.eval.runner import Rollouts

    qpos, qvel = (np.asarray(x, dtype=np.float64) for x in starts)
    if qpos.ndim != 2 or qvel.ndim != 2 or len(qpos) != len(qvel) or len(qpos) < 1:
        raise PromptError(f"refine: starts must be (S, nq) and (S, nv) arrays of equal length, got {qpos.shape} "
                          f"and {qvel.shape}")
    if steps < 1:
        raise PromptError(f"refine: steps must be >= 1, got {steps}")
    n_starts = len(qpos)

    def score(zs: np.ndarray) -> np.ndarray:
        k = len(zs)
        z = np.repeat(np.asarray(zs, dtype=np.float32), n_starts, axis=0)
        total = np.zeros(k * n_starts)

        def add(t: int, info: dict[str, Any], alive: np.ndarray) -> None:
            value = objective(info["final_obs"], info["final_qpos"], info["final_qvel"])
            total[:] += np.where(alive, np.asarray(value, dtype=np.float64), 0.0)

        roll = Rollouts(policy, k * n_starts, steps, num_threads)
        try:
            roll.run(policy, lambda t: z, np.tile(qpos, (k, 1)), np.tile(qvel, (k, 1)), add,
                     (lambda: on_step(k)) if on_step is not None else (lambda: None))
        finally:
            roll.close()
        return total.reshape(k, n_starts).mean(1) / steps

    return score


def reward_objective(task: RewardSpec) -> Objective:
    """A registry reward (or a RewardFn-like callable) as the per-step objective."""
    fn, label = reward_fn(task)

    def objective(obs: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.asarray(fn(obs, None, qpos, qvel), dtype=np.float64)

    objective.__name__ = label
    return objective


def goal_objective(goal: np.ndarray) -> Objective:
    """exp(-d_smpl(s, g) / β) for a goal observation g: 0.37 at the success threshold, 1 at the pose."""
    from fbcpr.metrics import GOAL_BETA, d_smpl

    goal = np.asarray(goal, dtype=np.float64)

    def objective(obs: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.exp(-d_smpl(obs, goal) / GOAL_BETA)

    return objective


def check_envs(population: int, starts: int) -> None:
    """A generation's envs (each holds a simulator) within MAX_ENVS: a PromptError naming both numbers when not,
    checked before any rollout (and by `fbcpr export` before any file is read)."""
    if population * starts > MAX_ENVS:
        raise PromptError(f"refine: population x starts = {population} x {starts} envs a generation, more than "
                          f"{MAX_ENVS}: use fewer starts or a smaller population")


def refine(policy: Policy, z0: np.ndarray, objective: Objective, starts: tuple[np.ndarray, np.ndarray],
           steps: int = 300, search: Search | None = None, num_threads: int | None = None,
           on_step: Callable[[int], None] | None = None,
           on_generation: Callable[[dict[str, float]], None] | None = None) -> Refined:
    """z0 refined for `objective` by rollouts of `policy` from `starts` (see the module docstring)."""
    search = search or Search()
    search.check()
    z0 = np.asarray(z0)
    if z0.shape != (policy.z_dim,):
        raise PromptError(f"refine: z0 must have shape ({policy.z_dim},), got {z0.shape}")
    check_envs(search.population, len(starts[0]))
    result = cross_entropy(rollout_score(policy, objective, starts, steps, num_threads, on_step), z0, search,
                           on_generation)
    result.episodes = (search.generations * search.population + 1) * len(starts[0])
    return result
