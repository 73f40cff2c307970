"""Reward prompts of the named tasks inferred once, at export, from more states than a checkpoint keeps.

A reward prompt is a weighted regression over reward-inference states, z ∝ Σ exp(τ r) r B(s) (`fbcpr.inference.prompt`).
With τ = 10 most of the weight falls on the few states of highest reward, so which states a sample holds moves z: two
draws of 50,000 of one model's own states walked 70.9 and 85.8 under the walk prompt. A checkpoint that ships keeps ~50k
states within its size budget, while a named task's z is z_dim numbers (64): `infer_reward_prompts` regresses them on
every state given to the export (e.g. 500,000 from ten rollout runs), and the checkpoint stores them in
reward_prompts.safetensors beside its subsample. `Prompt.reward` returns the stored z for a named task under the default
inference settings; a user's reward, a combined name or other settings are inferred from the subsample as before.

Some named tasks are prompted better by a nearby z than by the regression: a prompt can be refined by rollouts
(`fbcpr.inference.refine`, `fbcpr export --refine-prompts`). A refined task's stored z is the refined one; the
metadata keeps the regression's z beside it (`Prompt.reward(task, refined=False)` answers it) and how the search ran.

The z's belong to the weights they were inferred with: their metadata records a digest of the model's tensors,
a checkpoint whose weights do not match it is refused on load, and a save after the weights changed drops them.
They belong to their rewards' formulas too: the metadata records each task's revised terms
(`humanoid_env.tasks.rewards`), and a prompt stored for an older formula is dropped on load with a warning, so the
task is inferred from the checkpoint's reward states under today's formula.
"""
from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import torch

from fbcpr.core.checkpoint import PROMPTS_FILE, CheckpointError
from fbcpr.core.errors import InputError, PromptError
from fbcpr.inference.prompt import PromptableModel, regress_reward, reward_fn
from fbcpr.inference.refine import Search, project, refine, reward_objective, standing_starts
from fbcpr.nn.latents import TEMPERATURE

if TYPE_CHECKING:
    from fbcpr.methods.fb_cpr.model import FBCPRModel

#: The inference method stored prompts were made with: `Prompt.reward`'s default.
METHOD: Final = "weighted"
#: Most states prompts are inferred from at once: B of a million states takes 1 GB beside their 1.4 GB of
#: observations, and two pools of five own-states draws (250,000 states each) already agree to a cosine of 0.95.
MAX_STATES = 1_000_000
#: Most prompts a file may store (the registry names 54 tasks): each one's name is parsed on load.
MAX_PROMPTS = 4096


#: What a refined prompt's record holds besides its zero-shot z: the search's settings and its scores.
REFINEMENT_KEYS: Final = ("generations", "population", "starts", "steps", "seed", "score0", "score")


@dataclass(frozen=True)
class RewardPrompts:
    """z (on the model's sphere) per task name, the number of states they were inferred from, the digest of
    the weights they belong to, for each refined task its record: the zero-shot z ("z0"), REFINEMENT_KEYS ("score0"
    is the score of the z the search started from), the start z ("start") when the search did not start from z0, and
    the formula revisions of the tasks whose reward was revised."""

    z: dict[str, np.ndarray]
    states: int
    digest: str
    refined: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: per task, the revised terms of the reward formula its z was inferred for (`revisions_of`); none: as released
    revisions: dict[str, dict[str, int]] = field(default_factory=dict)

    def zero_shot(self, task: str) -> np.ndarray | None:
        """The regression's z for a stored task, refined or not; None for a task not stored."""
        if task in self.refined:
            return np.asarray(self.refined[task]["z0"], dtype=np.float32)
        return self.z.get(task)

    def to_tensors(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """What `save_checkpoint(reward_prompts=...)` writes: one tensor per task and the JSON metadata."""
        meta = {"states": self.states, "digest": self.digest, "method": METHOD, "temperature": TEMPERATURE,
                "refined": {task: {**rec, **{k: [float(v) for v in rec[k]] for k in ("z0", "start") if k in rec}}
                            for task, rec in self.refined.items()},
                "revisions": self.revisions}
        return {name: torch.as_tensor(z) for name, z in self.z.items()}, meta


def weights_digest(model: torch.nn.Module) -> str:
    """SHA-256 over every tensor of the model (names, shapes and bytes): the weights a stored prompt belongs to."""
    h = hashlib.sha256()
    for name, t in sorted(model.state_dict().items()):
        arr = t.detach().cpu().contiguous().numpy()
        h.update(f"{name}:{arr.dtype}:{arr.shape};".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def revisions_of(task: str) -> dict[str, int]:
    """The revised terms of a named task's reward formula (empty while all are as first released)."""
    fn, _ = reward_fn(task)
    return dict(fn.revisions()) if hasattr(fn, "revisions") else {}


def infer_reward_prompts(bfm: PromptableModel, tasks: Sequence[str]) -> RewardPrompts:
    """z for each named task, regressed on all of the model's reward-inference states (no subsample).

    A task these states cannot prompt (it pays nothing on any of them) is left out: its prompt is then inferred
    from the checkpoint's states when asked, and fails there with the reason. Raises PromptError for an unknown
    task name, InputError for more than MAX_STATES states, and CheckpointError for a model without reward states."""

    buf = bfm.reward_buffer
    if buf is None:
        raise CheckpointError(f"{bfm.source}: has no reward-inference states to infer reward prompts from")
    if len(buf["next_obs"]) > MAX_STATES:
        raise InputError(f"{len(buf['next_obs']):,} reward states to infer prompts from; at most {MAX_STATES:,} "
                         "(pool fewer runs with --reward-states-from)")
    fns = {label: fn for fn, label in map(reward_fn, tasks)}  # unknown names fail before any work
    b = bfm.backward(buf["next_obs"], as_tensor=True)
    z = {}
    for label, fn in fns.items():
        try:
            z[label] = bfm.project_z(regress_reward(fn, label, buf, b, METHOD, TEMPERATURE))
        except PromptError:
            continue
    return RewardPrompts(z, int(b.shape[0]), weights_digest(bfm.model),
                         revisions={t: r for t in z if (r := revisions_of(t))})


def load_reward_prompts(tensors: dict[str, torch.Tensor], meta: dict[str, Any], model: FBCPRModel,
                        where: Path) -> RewardPrompts:
    """Check stored prompts against the model they were loaded with; CheckpointError naming `where` and the
    problem (other weights, other settings, a wrong shape, NaN, or a name the task registry does not know)."""

    file = where / PROMPTS_FILE
    missing = [k for k in ("method", "temperature", "digest", "states") if k not in meta]
    if missing:
        raise CheckpointError(f"{file}: its metadata is missing ({', '.join(missing)}), so nothing says how or for "
                              "which weights these prompts were inferred; export the model again to infer them")
    if meta.get("method") != METHOD or meta.get("temperature") != TEMPERATURE:
        raise CheckpointError(f"{file}: made by {meta.get('method')!r} inference at temperature "
                              f"{meta.get('temperature')!r}; prompts use {METHOD!r} at {TEMPERATURE}")
    if meta.get("digest") != weights_digest(model):
        raise CheckpointError(f"{file}: these reward prompts were inferred for other weights than "
                              f"{where / 'model.safetensors'}; export the model again to infer its own")
    states = meta.get("states")
    if not isinstance(states, int) or states < 1:
        raise CheckpointError(f"{file}: metadata 'states' must be a positive count, got {states!r}")
    if len(tensors) > MAX_PROMPTS:
        raise CheckpointError(f"{file}: {len(tensors):,} prompts; a checkpoint stores at most {MAX_PROMPTS:,}")
    z_dim = int(model.z_dim)
    z, current = {}, {}
    for name, t in tensors.items():
        if tuple(t.shape) != (z_dim,) or not bool(torch.isfinite(t).all()):
            raise CheckpointError(f"{file}: {name!r} must be a finite ({z_dim},) z, got shape {tuple(t.shape)}")
        try:
            current[name] = revisions_of(name)
        except PromptError as err:
            raise CheckpointError(f"{file}: {err}") from None
        z[name] = t.float().cpu().numpy()
    refined = _refined(meta.get("refined", {}), z, z_dim, file)
    recorded = _revisions(meta.get("revisions", {}), z, file)
    stale = [t for t in z if recorded.get(t, {}) != current[t]]
    if stale:
        warnings.warn(f"{file}: stored for an older formula of their reward, these prompts are inferred from the "
                      f"reward states instead: {', '.join(stale)} (export the model again with --store-prompts "
                      "to store them)", UserWarning, stacklevel=2)
    return RewardPrompts({t: v for t, v in z.items() if t not in stale}, states, meta["digest"],
                         {t: r for t, r in refined.items() if t not in stale},
                         {t: r for t, r in recorded.items() if t not in stale})


def _revisions(records: Any, z: dict[str, np.ndarray], file: Path) -> dict[str, dict[str, int]]:
    """The formula revisions of stored metadata, each checked: a stored task mapped to {term name: count}."""
    ok = isinstance(records, dict) and all(
        task in z and isinstance(rec, dict) and all(isinstance(k, str) and isinstance(v, int) for k, v in rec.items())
        for task, rec in records.items())
    if not ok:
        raise CheckpointError(f"{file}: metadata 'revisions' must map stored task names to {{term: revision}}, got "
                              f"{str(records)[:200]}")
    return {task: dict(rec) for task, rec in records.items()}


def _refined(records: Any, z: dict[str, np.ndarray], z_dim: int, file: Path) -> dict[str, dict[str, Any]]:
    """The refinement records of stored metadata, each checked: a stored task, every key, a finite (z_dim,) z0."""
    if not isinstance(records, dict):
        raise CheckpointError(f"{file}: metadata 'refined' must map task names to records, "
                              f"got {type(records).__name__}")
    out = {}
    for task, rec in records.items():
        if task not in z:
            raise CheckpointError(f"{file}: a refinement is recorded for {task!r}, which stores no prompt")
        missing = [k for k in ("z0", *REFINEMENT_KEYS) if not isinstance(rec, dict) or k not in rec]
        if missing:
            raise CheckpointError(f"{file}: the refinement of {task!r} is missing {', '.join(missing)}")
        z0 = np.asarray(rec["z0"], dtype=np.float64)
        if z0.shape != (z_dim,) or not np.all(np.isfinite(z0)):
            raise CheckpointError(f"{file}: the refinement of {task!r} must keep a finite ({z_dim},) z0")
        if not all(isinstance(rec[k], (int, float)) and np.isfinite(rec[k]) for k in REFINEMENT_KEYS):
            raise CheckpointError(f"{file}: the refinement of {task!r} has a non-numeric setting or score")
        out[task] = {**{k: rec[k] for k in REFINEMENT_KEYS}, "z0": z0.astype(np.float32)}
        if "start" in rec:  # the search started from a given z, not from z0
            start = np.asarray(rec["start"], dtype=np.float64)
            if start.shape != (z_dim,) or not np.all(np.isfinite(start)):
                raise CheckpointError(f"{file}: the refinement of {task!r} must keep a finite ({z_dim},) start")
            out[task]["start"] = start.astype(np.float32)
    return out


def refine_reward_prompts(bfm: Any, tasks: Sequence[str], search: Search, starts: int, steps: int,
                          num_threads: int | None = None,
                          on_step: Callable[[int], None] | None = None,
                          start_from: dict[str, np.ndarray] | None = None) -> RewardPrompts:
    """`bfm`'s stored prompts with each of `tasks` refined by rollouts for its own reward from `starts` standing
    starts (drawn with `search.seed` + 1, as `fbcpr prompt --refine` draws them), starting from the zero-shot z, or
    from `start_from[task]` where given (a z found some other way, e.g. by screening many z's on the behaviour;
    kept in the record as "start", the zero-shot z as "z0").

    A task whose refined z scores no better on those starts than the z it started from keeps that z (the search
    returns the best mean it scored, its start included). Raises PromptError for a task that is not stored."""
    stored: RewardPrompts | None = bfm.reward_prompts
    if stored is None:
        raise PromptError("refining stored prompts needs stored prompts: export with --store-prompts too")
    missing = [t for t in tasks if t not in stored.z]
    if missing:
        raise PromptError(f"no stored prompt to refine for {', '.join(missing)} (stored: the named tasks the "
                          "reward states pay; `fbcpr tasks` lists the names)")
    given = start_from or {}
    stray = sorted(set(given) - set(tasks))
    if stray:
        raise PromptError(f"a start z is given for {', '.join(stray)}, which is not among the tasks to refine")
    z, refined = dict(stored.z), dict(stored.refined)
    for task in tasks:
        z0 = stored.zero_shot(task)
        assert z0 is not None  # stored, checked above
        first = project(given[task]).astype(np.float32) if task in given else z0  # the search starts on the sphere
        got = refine(bfm, first, reward_objective(task), standing_starts(starts, search.seed + 1), steps=steps,
                     search=search, num_threads=num_threads, on_step=on_step)
        z[task] = got.z
        refined[task] = {"generations": search.generations, "population": search.population, "starts": starts,
                         "steps": steps, "seed": search.seed, "score0": got.score0, "score": got.score, "z0": z0}
        if task in given:
            refined[task]["start"] = first
    return replace(stored, z=z, refined=refined)
