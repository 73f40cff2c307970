"""Demonstrations with actions: a clip together with the actions that produced it in the env.

A motion clip says where the body went; a demonstration also says how. The sampling planner
(`planner`, `lab/experiments/getup_planner.py --save`) writes them: its motions are what the env did with
its actions, so a learner can take them as transitions (`train.demonstrations`), which a clip of mocap cannot give.
On disk a demonstration is a clip `<name>.npz` and, beside it, `<name>.actions.npz` with the T actions between
its T + 1 frames and the action mapping they were taken under.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from motions.clip import Clip, ClipFormatError, load_clip, save_clip
from motions.limits import max_clip_frames
from motions.npz import read_npz

ACTIONS_SUFFIX = ".actions.npz"
#: Demonstration files read from one folder at most (each is bounded by the clip length limit).
MAX_DEMONSTRATIONS = 10_000


class DemonstrationError(ClipFormatError):
    """A demonstration folder or file that cannot be used; the message names it."""


@dataclass
class Demonstration:
    clip: Clip
    actions: np.ndarray   # (T, action_dim) in [-1, 1], between the clip's T + 1 frames
    action_mapping: str
    # (T, action_dim): an expert's actions at the first T frames where someone else acted (a learner's motion
    # labelled by the planner, DAgger); None where the actions are the expert's own
    labels: np.ndarray | None = None

    @property
    def target(self) -> np.ndarray:
        """What behaviour cloning pulls toward: the expert's labels where the rollout carries them, else its actions."""
        return self.actions if self.labels is None else self.labels


def clip_paths(folder: Path) -> list[Path]:
    """The clip files of a folder in name order, without the actions files of demonstrations kept there."""
    return sorted(p for p in folder.glob("*.npz") if not p.name.endswith(ACTIONS_SUFFIX))


def actions_path(clip_path: str | Path) -> Path:
    """Where the actions of the clip at `clip_path` are kept."""
    p = Path(clip_path)
    return p.with_name(p.name.removesuffix(".npz") + ACTIONS_SUFFIX)


def save_demonstration(demo: Demonstration, path: str | Path) -> Path:
    """Write the clip to `path` (.npz) and its actions (and labels, if any) beside it."""
    check_actions(demo.actions, demo.clip.n_frames, str(path))
    extra: dict[str, Any] = {}  # more arrays for np.savez's **kwds
    if demo.labels is not None:
        check_actions(demo.labels, demo.clip.n_frames, f"{path} (labels)")
        extra["labels"] = demo.labels.astype(np.float32)
    out = save_clip(demo.clip, path)
    np.savez(actions_path(out), actions=demo.actions.astype(np.float32), action_mapping=np.array(demo.action_mapping),
             **extra)
    return out


def check_actions(actions: np.ndarray, n_frames: int, where: str) -> None:
    """Raise DemonstrationError unless `actions` are (n_frames - 1, A) finite values in [-1, 1]."""
    if actions.ndim != 2 or len(actions) != n_frames - 1:
        raise DemonstrationError(f"{where}: actions must have shape ({n_frames - 1}, action_dim) for a clip of "
                                 f"{n_frames} frames, got {actions.shape}")
    if not np.isfinite(actions).all():
        raise DemonstrationError(f"{where}: actions contain NaN or inf")
    if np.abs(actions).max(initial=0.0) > 1.0:
        raise DemonstrationError(f"{where}: actions must lie in [-1, 1], found {np.abs(actions).max():.3g}")


def load_demonstration(clip_path: str | Path) -> Demonstration:
    """The clip at `clip_path` and its actions, both checked; errors name the file."""
    clip = load_clip(clip_path)
    apath = actions_path(clip_path)
    if not apath.exists():
        raise DemonstrationError(f"{apath}: no actions beside the clip {clip_path} (a demonstration needs both)")
    arrays = read_npz(apath, ("actions", "action_mapping", "labels"), DemonstrationError, "actions archive",
                      max_rows=max_clip_frames())
    if not {"actions", "action_mapping"} <= set(arrays):
        raise DemonstrationError(f"{apath}: needs members 'actions' and 'action_mapping' (and optionally 'labels'), "
                                 f"found {sorted(arrays)}")
    mapping = arrays["action_mapping"]
    if mapping.ndim != 0 or mapping.dtype.kind != "U":
        raise DemonstrationError(f"{apath}: action_mapping must be a string")
    actions = arrays["actions"]
    if actions.dtype.kind != "f":
        raise DemonstrationError(f"{apath}: actions must be floats, got {actions.dtype}")
    check_actions(actions, clip.n_frames, str(apath))
    labels = arrays.get("labels")
    if labels is not None:
        if labels.dtype.kind != "f":
            raise DemonstrationError(f"{apath}: labels must be floats, got {labels.dtype}")
        check_actions(labels, clip.n_frames, f"{apath} (labels)")
        labels = labels.astype(np.float32)
    return Demonstration(clip, actions.astype(np.float32), str(mapping), labels)


def load_demonstrations(folder: str | Path, max_transitions: int | None = None,
                        limit_name: str = "max_transitions") -> list[Demonstration]:
    """Every demonstration in `folder` (clips with actions beside them), in name order; more than
    `max_transitions` actions in all is an error naming `limit_name`, raised before the rest is read."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DemonstrationError(f"{folder}: no such demonstration folder")
    clips = clip_paths(folder)
    if not clips:
        raise DemonstrationError(f"{folder}: holds no demonstrations (<name>.npz with <name>{ACTIONS_SUFFIX})")
    if len(clips) > MAX_DEMONSTRATIONS:
        raise DemonstrationError(f"{folder}: {len(clips)} clips, over the limit of {MAX_DEMONSTRATIONS}")
    demos, total = [], 0
    for p in clips:
        demos.append(load_demonstration(p))
        total += len(demos[-1].actions)
        if max_transitions is not None and total > max_transitions:
            raise DemonstrationError(f"{folder}: over {limit_name} ({max_transitions:,} transitions) by {p.name}")
    return demos


def transitions(demos: list[Demonstration]) -> dict[str, np.ndarray]:
    """The demonstrations as replay transitions (obs, action, next_obs, and the next state's qpos and qvel, as
    the trainer stores them); none ends an episode."""
    def cat(f):
        return np.concatenate([f(d) for d in demos])
    return {"obs": cat(lambda d: d.clip.obs[:-1]), "action": cat(lambda d: d.actions),
            "next_obs": cat(lambda d: d.clip.obs[1:]), "qpos": cat(lambda d: d.clip.qpos[1:]),
            "qvel": cat(lambda d: d.clip.qvel[1:]), "terminated": np.zeros(sum(len(d.actions) for d in demos), bool)}
