"""The playground's simulation: one humanoid acting under a z that the user changes while it runs.

A `Source` is where the z comes from (a reward task, a goal pose, a tracked clip, a timeline) with one z per step
(a held prompt has one row, a clip one per frame; past the end the last is held) and what the live plot shows:
the task's reward for a reward prompt, exp(-d_smpl / 2) to the pose for a goal, and to the clip's next frame for a
clip. `Session.use` swaps the source of the running body without a reset; a prompt that fails raises before
anything changes, so the body keeps its last good prompt. No web code here: the page (`page.py`) drives a Session.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fbcpr.core.errors import PromptError
from fbcpr.inference.bfm import BFM
from fbcpr.inference.prompt import GOAL_REWARD_SCALE, goal_observation, load_motion, reward_fn
from fbcpr.inference.timeline import Timeline
from fbcpr.metrics import d_smpl
from humanoid_env.env import HumanoidEnv
from humanoid_env.inits import DefaultInit, FallInit

#: (step within the segment, obs, action, qpos, qvel) -> the plotted reward of that step
Score = Callable[[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray], float]
#: Horizontal speed (m/s) a push adds to the pelvis, in a random direction.
PUSH_SPEED = 1.5
#: Episodes never end on their own in the playground: the user resets.
ENDLESS = 2**62


@dataclass(frozen=True)
class Source:
    """Where z comes from: one z per step (`z`, (steps, z_dim)), which segment each step is in, and per segment a
    label and the reward the plot shows."""

    kind: str
    label: str
    detail: str
    z: np.ndarray
    segment: np.ndarray
    starts: tuple[int, ...]
    labels: tuple[str, ...]
    scores: tuple[Score, ...]

    def at(self, t: int) -> tuple[np.ndarray, int, int]:
        """(z, segment, step within the segment) at step t of the source; the last row is held past the end."""
        t = min(t, len(self.z) - 1)
        seg = int(self.segment[t])
        return self.z[t], seg, t - self.starts[seg]

    def describe(self, t: int) -> str:
        """What z is now, for the page: the kind, the name, where it came from and, for clips and timelines,
        how far along they are."""
        _, seg, local = self.at(t)
        text = f"{self.kind} **{self.label}** ({self.detail})"
        if self.kind == "timeline":
            text += f": segment {seg + 1}/{len(self.labels)}, {self.labels[seg]}"
        if len(self.z) > 1:
            done = " (ended: holding its last z)" if t >= len(self.z) else ""
            text += f", step {min(t, len(self.z))}/{len(self.z)}{done}"
        return text


def single(kind: str, label: str, detail: str, z: np.ndarray, score: Score) -> Source:
    z = np.atleast_2d(np.asarray(z, dtype=np.float32))
    return Source(kind, label, detail, z, np.zeros(len(z), np.int64), (0,), (label,), (score,))


def proximity(obs: np.ndarray, goal: np.ndarray) -> float:
    """exp(-d_smpl / 2): 1 at the pose, the goal metric's distance scale (`fbcpr.inference.prompt.goal_reward`)."""
    return float(np.exp(-d_smpl(obs, goal) / GOAL_REWARD_SCALE))


class Prompts:
    """Builds Sources from what the page offers; every failure is a PromptError whose message the page shows."""

    def __init__(self, bfm: BFM) -> None:
        self.bfm = bfm

    def reward(self, task: str) -> Source:
        fn, label = reward_fn(task)
        z = self.bfm.prompt.reward(label)
        stored = self.bfm.reward_prompts
        if stored is not None and label in stored.refined:
            detail = "stored prompt, refined by rollouts"
        elif stored is not None and label in stored.z:
            detail = f"stored prompt, inferred from {stored.states:,} states"
        else:
            detail = "inferred from the model's reward states"

        def score(_t: int, obs: np.ndarray, action: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> float:
            return float(fn(obs[None], action[None], qpos[None], qvel[None])[0])

        return single("reward", label, detail, z, score)

    def goal(self, name: str) -> Source:
        goal = goal_observation(name, self.bfm.obs_dim)[0]
        z = self.bfm.prompt.goal(name)
        return single("goal", name, "B of the pose", z, lambda _t, obs, *_: proximity(obs, goal))

    def clip(self, spec: str | Path, label: str | None = None) -> Source:
        clip = load_motion(spec)
        z = self.bfm.prompt.track(clip)
        ref = clip.obs
        return single("clip", label or clip.name, f"tracked, {len(clip.obs)} frames",
                      z, lambda t, obs, *_: proximity(obs, ref[min(t + 1, len(ref) - 1)]))

    def timeline(self, text: str) -> Source:
        tl = Timeline.from_string(self.bfm.prompt, text)
        parts = [self._part(seg.kind, seg.label) for seg in tl.segments]
        starts = tuple(int(s) for s in np.cumsum([0] + [seg.steps for seg in tl.segments[:-1]]))
        return Source("timeline", text, f"{len(tl.segments)} segments", tl.z_per_step().astype(np.float32),
                      tl.segment_index(), starts, tuple(seg.label for seg in tl.segments),
                      tuple(p.scores[0] for p in parts))

    def _part(self, kind: str, label: str) -> Source:
        return {"reward": self.reward, "goal": self.goal, "clip": self.clip}[kind](label)


class Session:
    """The running body: `step` advances one control step (30 Hz) under the current source; `use`, `reset` and
    `push` change it between steps (from the page's threads: a lock keeps each change whole)."""

    def __init__(self, bfm: BFM, source: Source, seed: int = 0) -> None:
        self.bfm = bfm
        self.env = HumanoidEnv(action_mapping=bfm.action_mapping, max_episode_steps=ENDLESS)
        self.rng = np.random.default_rng(seed)
        self.lock = threading.Lock()
        self.source, self.t = source, 0
        self.stand, self.fall = DefaultInit(), FallInit(height=(0.1, 0.3))
        self.obs, info = self.env.reset(seed=seed)
        self.qpos, self.qvel = info["qpos"], info["qvel"]
        self.reward = 0.0
        self.steps = 0

    def use(self, source: Source) -> None:
        """Prompt the running body with a new source, from its first step, without touching the body."""
        with self.lock:
            self.source, self.t = source, 0

    def reset(self, fallen: bool = False) -> None:
        """A new start: standing (small joint noise), or lying on the floor in a random pose."""
        qpos, qvel = (self.fall if fallen else self.stand).sample(self.rng, 1)
        with self.lock:
            self._set(qpos[0], qvel[0])

    def push(self, speed: float = PUSH_SPEED) -> None:
        """Add `speed` m/s of horizontal pelvis velocity in a random direction."""
        angle = self.rng.uniform(0, 2 * np.pi)
        with self.lock:
            qvel = self.qvel.copy()
            qvel[:2] += speed * np.array([np.cos(angle), np.sin(angle)])
            self._set(self.qpos.copy(), qvel)

    def _set(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        self.obs, info = self.env.reset(options={"qpos": qpos, "qvel": qvel})
        self.qpos, self.qvel = info["qpos"], info["qvel"]

    def step(self) -> float:
        """One control step under the current z; returns the plotted reward. A diverged simulation restarts
        standing (the env never hands out NaN, and the page keeps running)."""
        with self.lock:
            z, seg, local = self.source.at(self.t)
            action = self.bfm.act(self.obs, z)
            self.obs, _, terminated, _, info = self.env.step(action)
            self.qpos, self.qvel = info["qpos"], info["qvel"]
            self.reward = self.source.scores[seg](local, self.obs, action, self.qpos, self.qvel)
            self.t += 1
            self.steps += 1
            if info["diverged"]:
                self._set(*(x[0] for x in self.stand.sample(self.rng, 1)))
            return self.reward


def clip_choices(folder: Path, extra: Sequence[str | Path], builtins: Sequence[str], limit: int = 500
                 ) -> dict[str, str]:
    """Label -> clip spec for the page: the clips given on the command line, the .npz files under the data folder
    (at most `limit`, by path) and the built-in synthetic clips."""
    out = {str(p): str(p) for p in extra}
    if folder.is_dir():
        for path in sorted(folder.rglob("*.npz"))[:limit]:
            out[str(path.relative_to(folder))] = str(path)
    out.update({f"{name} (built-in)": name for name in builtins})
    return out


def check_clip_files(paths: Sequence[Path]) -> None:
    """PromptError unless every clip given on the command line is a file (its content is read when picked)."""
    missing = [str(p) for p in paths if not Path(p).is_file()]
    if missing:
        raise PromptError(f"--clip: {', '.join(missing)}: no such clip file")
