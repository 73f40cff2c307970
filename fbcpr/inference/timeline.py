"""Timeline prompts: several prompts played back to back, e.g. walk 4 s, then jump 2 s, then sit 4 s.

The text form is "ITEM:SECONDS,ITEM:SECONDS,...", where ITEM is a clip file or a built-in clip name (tracked frame by
frame), a goal name, or a reward task (combined rewards like "move-ego-0-2*raisearms-l-l" included). Each segment turns
into one z per control step (30 Hz); the policy switches z at segment boundaries and the state carries over, which is
how a BFM stitches motions without any extra training.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Union

import numpy as np

from fbcpr.core.errors import PromptError
from fbcpr.inference.prompt import Prompt, builtin_clip_names
from humanoid_env.model import CONTROL_HZ

Kind = Literal["reward", "goal", "clip", "z"]
#: A timeline item: a text spec (clip path, goal name or reward task) or an explicit z vector.
Item = Union[str, Path, np.ndarray]


@dataclass(frozen=True)
class Segment:
    """One prompt held for `steps` control steps; `z` is (steps, d)."""

    label: str
    kind: Kind
    seconds: float
    z: np.ndarray

    @property
    def steps(self) -> int:
        return int(self.z.shape[0])


def parse_timeline(text: str) -> list[tuple[str, float]]:
    """Split "a:4,b:2.5" into [("a", 4.0), ("b", 2.5)]; clear errors for empty items and bad durations."""
    items = [part.strip() for part in text.split(",")]
    if not text.strip() or any(not part for part in items):
        raise PromptError(f"timeline {text!r}: expected comma-separated ITEM:SECONDS entries, found an empty entry")
    out = []
    for part in items:
        spec, sep, secs = part.rpartition(":")
        if not sep or not spec.strip():
            raise PromptError(f"timeline entry {part!r}: expected ITEM:SECONDS, e.g. jump-2:2")
        try:
            seconds = float(secs)
        except ValueError:
            raise PromptError(f"timeline entry {part!r}: duration {secs!r} is not a number of seconds") from None
        check_seconds(f"timeline entry {part!r}", seconds)
        out.append((spec.strip(), seconds))
    return out


#: Longest segment and whole timeline: an hour is 108,000 control steps of z (about 110 MB at z_dim 256).
MAX_SECONDS = 3600.0


def check_seconds(where: str, seconds: float, limit: float = MAX_SECONDS) -> None:
    """PromptError unless a duration is finite, positive and at most `limit`: a typo like 1e9 s would otherwise
    allocate one z per control step for 30 years."""
    if not (np.isfinite(seconds) and 0 < seconds <= limit):
        raise PromptError(f"{where}: duration must be a positive number of seconds, at most {limit:g}, got {seconds:g}")


def classify(spec: str) -> Kind:
    """A clip file, a goal name, a reward task, or a built-in clip name, in that order; else a clear error."""
    from humanoid_env.tasks import get_reward
    from humanoid_env.tasks.goals import goal_names

    if spec.endswith(".npz") or Path(spec).is_file():
        return "clip"
    if spec in goal_names():
        return "goal"
    try:
        get_reward(spec)
        return "reward"
    except ValueError as err:
        if spec in builtin_clip_names():
            return "clip"
        raise PromptError(f"timeline item {spec!r} is not a clip file, a goal pose, a built-in clip "
                          f"({', '.join(builtin_clip_names())}) or a reward task: {err}") from None


class Timeline:
    """Segments of per-step zs; iterate it to get one z per control step."""

    def __init__(self, segments: Sequence[Segment]) -> None:
        if not segments:
            raise PromptError("a timeline needs at least one segment")
        self.segments = list(segments)

    @classmethod
    def build(cls, prompt: Prompt, items: Sequence[tuple[Item, float]], fps: float = CONTROL_HZ) -> Timeline:
        """Infer the z of every (item, seconds) pair; reward and goal zs are held, clips are tracked."""
        total = 0.0
        for i, (item, seconds) in enumerate(items, 1):  # all bounds first: no prompt runs for a timeline that fails
            label = "z" if isinstance(item, np.ndarray) else str(item)
            check_seconds(f"timeline segment {i} ({label})", seconds)
            if seconds * fps < 1 - 1e-6:  # a whole control step would play, and the table would report less
                raise PromptError(f"timeline segment {i} ({label}): {seconds:g} s is shorter than one control step "
                                  f"(1/{fps:g} s); give at least {1 / fps:.4g} s")
            total += seconds
            if total > MAX_SECONDS:
                raise PromptError(f"timeline segment {i} ({label}): the timeline would last {total:g} s, "
                                  f"longer than {MAX_SECONDS:g} s")
        segments = []
        for item, seconds in items:
            steps = max(1, int(round(seconds * fps)))
            kind: Kind
            if isinstance(item, np.ndarray):
                if item.shape != (prompt.bfm.z_dim,):
                    raise PromptError(f"timeline z must have shape ({prompt.bfm.z_dim},), got {item.shape}")
                kind, label, z = "z", "z", prompt.mix([(item, 1.0)])
            else:
                label = str(item)
                kind = classify(label)
                if kind == "clip":
                    z = prompt.track(label)
                elif kind == "goal":
                    z = prompt.goal(label)
                else:
                    z = prompt.reward(label)
            z = np.atleast_2d(z)
            # Held prompts repeat one z; a tracked clip plays its per-step zs and holds the last one if time remains.
            rows = np.minimum(np.arange(steps), z.shape[0] - 1)
            segments.append(Segment(label=label, kind=kind, seconds=float(seconds), z=z[rows]))
        return cls(segments)

    @classmethod
    def from_string(cls, prompt: Prompt, text: str, fps: float = CONTROL_HZ) -> Timeline:
        """Parse "move-ego-0-2:4,jump-2:2,sitonground:4" and infer every segment's zs."""
        return cls.build(prompt, parse_timeline(text), fps=fps)

    @property
    def n_steps(self) -> int:
        return sum(s.steps for s in self.segments)

    def z_per_step(self) -> np.ndarray:
        """(n_steps, d): the z to use at every control step."""
        return np.concatenate([s.z for s in self.segments])

    def segment_index(self) -> np.ndarray:
        """(n_steps,): which segment each step belongs to (for labels in videos and per-segment returns)."""
        return np.repeat(np.arange(len(self.segments)), [s.steps for s in self.segments])

    def __iter__(self) -> Iterator[np.ndarray]:
        for seg in self.segments:
            yield from seg.z
