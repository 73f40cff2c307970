"""Behaviour checks: does the body do what the prompt names? A task's reward can be earned without the behaviour
(bobbing scores on a jump task), so each family here is judged by a physical test of the body, read off the
observations and independent of the task's reward, next to the zero-action and random floors.

Every family is prompted with one reward task (the goal family with each named pose) and run from the start its
rule names (standing, pushed or fall) and from one other start, the same starts for every agent. A family passes
when the judged agent's score from its own start (the share of episodes that meet the rule; for the goal family,
the mean success) reaches the family's `need` and beats each floor's score from that start by `MARGIN`: a rule
that the zero action or random actions also meet says nothing about the model. The floors ignore z, so their
episodes from one start are shared by every family.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from fbcpr.core.errors import InputError
from fbcpr.eval.upright import FALLEN, PUSH, STANDING, got_up
from fbcpr.metrics import GOAL_BETA, d_smpl, goal_proximity, goal_success
from humanoid_env.model import CONTROL_HZ
from humanoid_env.tasks.features import Features

STARTS = ("standing", "pushed", "fall")
#: the start shown beside a family's own: a pushed stand beside a quiet one, the rest beside a fall or a stand
OTHER_START = {"standing": "fall", "pushed": "standing", "fall": "standing"}
PASS_SHARE = 0.5
#: how far the judged agent's score must exceed each floor's (zero action, random actions) from the family's own
#: start: two episodes in eight, the standard error of the difference of two shares near 0.5 over 8 episodes each
MARGIN = 0.25
#: envs one vector env steps at once
CHUNK = 96
#: the recorded observations grow with episodes x steps: 9,600 (32 episodes of 300 steps) keep ~250 MB
MAX_EPISODE_STEPS = 9_600
FLIGHT_CLEARANCE, JUMP_GAIN = 0.05, 0.15
FEET = ("L_Ankle", "L_Toe", "R_Ankle", "R_Toe")


class Trace:
    """Body quantities of recorded episodes, obs (T, E, 358), as (T, E, ...) arrays."""

    def __init__(self, obs: np.ndarray) -> None:
        self.shape = obs.shape[:2]
        self.f = Features(obs.reshape(-1, obs.shape[-1]))

    def _back(self, flat: np.ndarray) -> np.ndarray:
        return flat.reshape(*self.shape, *flat.shape[1:])

    def z(self, body: str) -> np.ndarray:
        return self._back(self.f.z(body))

    def axis_x(self, body: str) -> np.ndarray:
        return self._back(self.f.axis_x(body))

    def com_vel(self) -> np.ndarray:
        return self._back(self.f.com_vel)

    def yaw_rate(self) -> np.ndarray:
        """Pelvis angular velocity about the world vertical (the heading frame keeps z)."""
        return self._back(self.f.angvel("Pelvis")[:, 2])


@lru_cache(maxsize=1)
def standing_heights() -> dict[str, float]:
    """Body heights of the rest standing pose: the reference a jump's apex and flight are measured from."""
    from humanoid_env.inits import DefaultInit
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe

    qpos, qvel = DefaultInit(0.0, 0.0).sample(np.random.default_rng(0), 1)
    f = Features(observe(load_model(), qpos, qvel).reshape(1, -1))
    return {b: float(f.z(b)[0]) for b in ("Pelvis", "Head", *FEET)}


def _last(x: np.ndarray, seconds: float) -> np.ndarray:
    return x[-max(1, round(seconds * CONTROL_HZ)):]


def _half(x: np.ndarray) -> np.ndarray:
    return x[len(x) // 2:]


Judge = Callable[[Trace], tuple[np.ndarray, dict[str, np.ndarray]]]


def _stand(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    pelvis, v = _half(tr.z("Pelvis")), _half(tr.com_vel())
    speed = np.hypot(v[..., 0], v[..., 1]).mean(0)
    return (pelvis > STANDING).all(0) & (speed < 0.3), {"speed": speed, "min_pelvis": pelvis.min(0)}


def _move(angle: float, speed: float) -> Judge:
    def judge(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        chest = _half(tr.axis_x("Chest"))[..., :2]
        a = np.arctan2(chest[..., 1], chest[..., 0]) + np.deg2rad(angle)
        v = _half(tr.com_vel())[..., :2]
        along = (v[..., 0] * np.cos(a) + v[..., 1] * np.sin(a)).mean(0)
        across = (-v[..., 0] * np.sin(a) + v[..., 1] * np.cos(a)).mean(0)
        heading = np.degrees(np.abs(np.arctan2(across, along)))
        up = (_half(tr.z("Pelvis")) > FALLEN).all(0)
        ok = up & (along >= 0.75 * speed) & (along <= 1.5 * speed) & (heading <= 30.0)
        return ok, {"speed": along, "heading_error_deg": heading}
    return judge


def _jump(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rest = standing_heights()
    settled = slice(CONTROL_HZ, None)  # a fall start drops from up to 1 m: that is not a jump
    pelvis = tr.z("Pelvis")[settled]
    # feet raised by a body lying on its back are not a flight: the pelvis must be at standing height
    flight = np.all([tr.z(b)[settled] > rest[b] + FLIGHT_CLEARANCE for b in FEET], axis=0) & (pelvis > STANDING)
    gain = pelvis.max(0) - rest["Pelvis"]
    return flight.any(0) & (gain >= JUMP_GAIN), {"apex_gain": gain, "flight_steps": flight.sum(0).astype(float)}


def _sit(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    pelvis, head = _last(tr.z("Pelvis"), 1.0), _last(tr.z("Head"), 1.0)
    knee = np.minimum(_last(tr.z("L_Knee"), 1.0), _last(tr.z("R_Knee"), 1.0))
    seated = (pelvis < 0.5) & ((pelvis < 0.25) | (knee < 0.15)) & (head - pelvis > 0.35)
    return seated.all(0), {"pelvis": pelvis.mean(0), "torso_rise": (head - pelvis).mean(0), "held": seated.mean(0)}


def _lie_up(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    pelvis, head = _last(tr.z("Pelvis"), 1.0), _last(tr.z("Head"), 1.0)
    face = _last(tr.axis_x("Chest")[..., 2], 1.0)
    lying = np.asarray(((pelvis < 0.3) & (head < 0.35) & (face > 0.7)).all(0))
    return lying, {"pelvis": pelvis.mean(0), "chest_up": face.mean(0)}


def _get_up(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    pelvis = tr.z("Pelvis")
    return got_up(pelvis), {"pelvis": _last(pelvis, 1.0).mean(0)}


def _crouch(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    pelvis, head = _last(tr.z("Pelvis"), 1.0), _last(tr.z("Head"), 1.0)
    ankles = np.maximum(_last(tr.z("L_Ankle"), 1.0), _last(tr.z("R_Ankle"), 1.0))
    knees = np.minimum(_last(tr.z("L_Knee"), 1.0), _last(tr.z("R_Knee"), 1.0))
    ok = (pelvis > 0.3) & (pelvis < 0.7) & (ankles < 0.2) & (knees > 0.2) & (head - pelvis > 0.35)
    return ok.all(0), {"pelvis": pelvis.mean(0), "held": ok.mean(0)}


def _hands_up(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    head, pelvis = _last(tr.z("Head"), 1.0), _last(tr.z("Pelvis"), 1.0)
    lower = np.minimum(_last(tr.z("L_Wrist"), 1.0), _last(tr.z("R_Wrist"), 1.0)) - head
    return ((lower > 0.05) & (pelvis > STANDING)).all(0), {"lower_wrist_over_head": lower.mean(0)}


def _spin(rate: float) -> Judge:
    def judge(tr: Trace) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        w = np.sign(rate) * _half(tr.yaw_rate()).mean(0)
        up = (_half(tr.z("Pelvis")) > FALLEN).all(0)
        return up & (w >= 0.5 * abs(rate)), {"yaw_rate": w}
    return judge


@dataclass(frozen=True)
class Family:
    """One behaviour: the prompt it is asked with, the start its pass rule reads, the rule in words and as code."""

    name: str
    prompt: str
    start: str
    rule: str
    judge: Judge | None = field(default=None, compare=False)
    need: float = PASS_SHARE

    @property
    def starts(self) -> tuple[str, str]:
        """The start the rule reads, then the one shown beside it."""
        return self.start, OTHER_START[self.start]


FAMILIES: tuple[Family, ...] = (
    Family("stand", "move-ego-0-0", "pushed", "pelvis > 0.8 m and mean speed < 0.3 m/s over the last 5 s, from a "
           "pushed standing start (which topples the zero action)", _stand),
    Family("walk", "move-ego-0-2", "standing", "1.5-3 m/s along the prompted direction, heading error <= 30 deg, "
           "pelvis > 0.6 m, over the last 5 s", _move(0.0, 2.0)),
    Family("run", "move-ego-0-4", "standing", "3-6 m/s along the prompted direction, heading error <= 30 deg, "
           "pelvis > 0.6 m, over the last 5 s", _move(0.0, 4.0)),
    Family("jump", "jump-2", "standing", f"a flight phase (every foot {FLIGHT_CLEARANCE:g} m above its standing "
           f"height, pelvis > {STANDING:g} m) and the pelvis {JUMP_GAIN:g} m above standing, after the first second",
           _jump),
    Family("sit", "sitonground", "standing", "over the last second: pelvis < 0.5 m on the knees or the seat, "
           "head 0.35 m above the pelvis", _sit),
    Family("lie_face_up", "lieonground-up", "standing", "over the last second: pelvis < 0.3 m, head < 0.35 m, "
           "chest facing up", _lie_up),
    Family("get_up", "move-ego-0-0", "fall", "pelvis > 0.8 m over the last second", _get_up),
    Family("crouch", "crouch-0", "standing", "over the last second: pelvis 0.3-0.7 m, feet down, knees up, "
           "torso upright", _crouch),
    Family("hands_up", "raisearms-h-h", "standing", "over the last second: both wrists 0.05 m above the head, "
           "pelvis > 0.8 m", _hands_up),
    Family("spin", "rotate-z-5-0.8", "standing", "at least 2.5 rad/s about the vertical over the last 5 s, "
           "pelvis > 0.6 m", _spin(5.0)),
    Family("goal_poses", "goals", "standing", f"the paper's success (d <= {GOAL_BETA:g} at some step), mean over "
           "the named poses, >= 0.3; beside the zero floor, a pose reached no more often than by zero action "
           "counts 0", need=0.3),
)
FAMILY_NAMES = tuple(f.name for f in FAMILIES)


def families(names: Sequence[str] | None = None) -> list[Family]:
    """The families to run, in table order; an unknown name is an error that lists the known ones."""
    if not names:
        return list(FAMILIES)
    unknown = [n for n in names if n not in FAMILY_NAMES]
    if unknown:
        raise InputError(f"unknown behaviour famil{'ies' if len(unknown) > 1 else 'y'} {', '.join(unknown)}: "
                         f"choose from {', '.join(FAMILY_NAMES)}")
    return [f for f in FAMILIES if f.name in names]


def start_states(episodes: int, seed: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The standing, pushed and fall starts every agent and family sees (fall starts drawn with seed + 1; pushed
    ones, the standing pose with `PUSH`'s joint-angle and velocity noise, from a stream of their own)."""
    from humanoid_env.inits import DefaultInit, FallInit

    return {"standing": DefaultInit().sample(np.random.default_rng(seed), episodes),
            "fall": FallInit().sample(np.random.default_rng(seed + 1), episodes),
            "pushed": DefaultInit(*PUSH).sample(np.random.default_rng((seed, 2)), episodes)}


def beats_floors(score: float, floors: Sequence[float], need: float) -> bool:
    """The pass rule: `score` reaches `need` and exceeds every floor's score by `MARGIN` (to 1e-6: shares of
    episodes are exact fractions)."""
    return score >= need and all(round(score - f, 6) >= MARGIN for f in floors)


@dataclass
class Batch:
    """Episodes to roll out together: one z and one start state per env."""

    z: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray


#: what a batch's watcher gets after each step t (t = -1: the start): the slice of envs, their obs and qpos, and
#: which of them have diverged so far (the env restarts those, so their episode is over)
Watch = Callable[[int, slice, np.ndarray, np.ndarray, np.ndarray], None]


def run_batch(agent: Any, batch: Batch, steps: int, on_obs: Watch, advance: Callable[[int], None] = lambda n: None,
              num_threads: int | None = None) -> None:
    """Roll out every env of `batch` for `steps` steps, `CHUNK` envs at a time (bounds the memory of the env), on
    the benchmark's `Rollouts`; `advance(n)` hears of the env steps done."""
    from fbcpr.eval.runner import Rollouts

    n = len(batch.qpos)
    for lo in range(0, n, CHUNK):
        envs = slice(lo, min(n, lo + CHUNK))
        size = envs.stop - lo
        roll = Rollouts(agent, size, steps, num_threads)
        try:
            z = batch.z[envs]

            def start(obs: np.ndarray, envs: slice = envs) -> None:
                on_obs(-1, envs, obs, batch.qpos[envs], np.zeros(obs.shape[0], bool))

            def step(t: int, info: dict[str, Any], alive: np.ndarray, envs: slice = envs) -> None:
                on_obs(t, envs, info["final_obs"], info["final_qpos"], ~alive)

            def z_at(t: int, z: np.ndarray = z) -> np.ndarray:
                return z

            def done(size: int = size) -> None:
                advance(size)

            roll.run(agent, z_at, batch.qpos[envs], batch.qvel[envs], step, done, on_start=start)
        finally:
            roll.close()


#: refinement: standing or fall starts each candidate z is rolled out from, apart from the checks' own
REFINE_STARTS = 8
#: search(agent, task, starts, on_step) -> z: a task's prompt refined by rollouts from `starts`; `on_step(k)` hears
#: of k candidate episodes stepped (the caller builds it, e.g. from `fbcpr.inference.refine`)
Search = Callable[[Any, str, tuple[np.ndarray, np.ndarray], Callable[[int], None] | None], np.ndarray]


@dataclass(frozen=True)
class Refinement:
    """How each family's task prompt is refined before its checks: the search, its generations (for the record) and
    the env steps it costs a prompt (for the progress bar)."""

    search: Search
    generations: int
    env_steps: int


def plan(fams: Sequence[Family], model: bool, refined: bool) -> tuple[dict[str, list[str]], dict[str, str]]:
    """(starts by prompt key, prompt key by family): each prompt runs from its families' own and other starts. A
    family's key is its task ("TASK@START" when refined: a z per kind of start); the goal family's are each pose's,
    "goal:NAME". A floor runs one empty prompt, keyed "", from every start any family reads."""
    from humanoid_env.tasks import GOALS

    starts: dict[str, set[str]] = {}
    key_of: dict[str, str] = {}
    for f in fams:
        if not model:
            keys = [""]
        elif f.judge is None:
            keys = [f"goal:{g}" for g in GOALS]
        else:
            key_of[f.name] = f"{f.prompt}@{f.start}" if refined else f.prompt
            keys = [key_of[f.name]]
        for k in keys:
            starts.setdefault(k, set()).update(f.starts)
    if not model:
        key_of = {f.name: "" for f in fams}
    return {k: [s for s in STARTS if s in v] for k, v in starts.items()}, key_of


def _prompts(agent: Any, fams: Sequence[Family], refine: Refinement | None, seed: int,
             on_refine: Callable[[int], None] | None = None
             ) -> tuple[dict[str, np.ndarray], dict[str, list[str]], dict[str, str]]:
    """(z by prompt key, starts by prompt key, prompt key by family), keyed as `plan` says. A family's z is its
    task's prompt, refined from `REFINE_STARTS` starts of the family's own kind (drawn apart from the checks') when
    `refine` is given; a goal pose's is its goal prompt; a floor's is empty."""
    from humanoid_env.tasks import goal_obs

    starts, key_of = plan(fams, agent.z_dim > 0, refine is not None)
    if agent.z_dim == 0:
        return {"": np.zeros(0, np.float32)}, starts, key_of
    zs = {k: np.asarray(agent.goal_z(goal_obs(k[5:])), np.float32) for k in starts if k.startswith("goal:")}
    for f in fams:
        key = key_of.get(f.name)
        if key is None or key in zs:
            continue
        if refine is None:
            zs[key] = np.asarray(agent.reward_z(f.prompt), np.float32)
        else:
            own = start_states(REFINE_STARTS, seed + 1000)[f.start]
            zs[key] = np.asarray(refine.search(agent, f.prompt, own, on_refine), np.float32)
    return zs, starts, key_of


def refine_env_steps(fams: Sequence[Family], refine: Refinement | None) -> int:
    """Env steps that refining the families' prompts costs (each distinct task and start once)."""
    if refine is None:
        return 0
    return len({(f.prompt, f.start) for f in fams if f.judge is not None}) * refine.env_steps


@dataclass
class AgentRun:
    """What one agent did, per (prompt key, start): observations (T+1, E, 358) of the behaviour prompts, distances
    (E, T) to each goal pose (infinite once diverged), which episodes diverged (E,), and episode 0's body states
    (T+1, nq) for pictures."""

    obs: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    diverged: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    dist: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    qpos0: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    key_of: dict[str, str] = field(default_factory=dict)  # each behaviour family's prompt key

    def find(self, table: dict[tuple[str, str], np.ndarray], prompt: str, start: str) -> np.ndarray:
        """A floor ran one prompt ("") for every family."""
        return table[(prompt, start)] if (prompt, start) in table else table[("", start)]


def run_agent(agent: Any, fams: Sequence[Family], starts: dict[str, tuple[np.ndarray, np.ndarray]], steps: int,
              advance: Callable[[int], None] = lambda n: None, num_threads: int | None = None,
              refine: Refinement | None = None, seed: int = 0,
              on_refine: Callable[[int], None] | None = None) -> AgentRun:
    """Every (prompt, start) of `fams` for `agent`, all episodes in one batch; a goal pose's episodes keep only
    their distance to the pose. With `refine`, each family's prompt is refined first (`_prompts`)."""
    from humanoid_env.model import NQ
    from humanoid_env.observation import OBS_DIM
    from humanoid_env.tasks import goal_obs

    zs, need, key_of = _prompts(agent, fams, refine, seed, on_refine)
    keys = [(p, s) for p in zs for s in need[p]]
    episodes = len(starts["standing"][0])
    n = len(keys) * episodes
    batch = Batch(z=np.concatenate([np.repeat(zs[p][None], episodes, 0) for p, _ in keys]),
                  qpos=np.concatenate([starts[s][0] for _, s in keys]),
                  qvel=np.concatenate([starts[s][1] for _, s in keys]))
    goal_env = np.array([p.startswith("goal:") for p, _ in keys]).repeat(episodes)
    slot = np.where(goal_env, np.cumsum(goal_env) - 1, np.cumsum(~goal_env) - 1)  # index among its own kind
    targets = np.stack([goal_obs(p[5:]) for p, _ in keys if p.startswith("goal:")]).repeat(episodes, 0) \
        if goal_env.any() else np.zeros((0, OBS_DIM), np.float32)
    obs = np.empty((steps + 1, int((~goal_env).sum()), OBS_DIM), np.float32)
    dist = np.empty((steps + 1, int(goal_env.sum())), np.float32)
    first = np.arange(0, n, episodes)
    qpos0 = np.empty((steps + 1, len(keys), NQ))
    dead = np.zeros(n, bool)

    def keep(t: int, envs: slice, o: np.ndarray, q: np.ndarray, diverged: np.ndarray) -> None:
        dead[envs] |= diverged
        goal, idx = goal_env[envs], slot[envs]
        obs[t + 1, idx[~goal]] = o[~goal]
        dist[t + 1, idx[goal]] = np.where(dead[envs][goal], np.inf, d_smpl(o[goal], targets[idx[goal]]))
        here = first[(first >= envs.start) & (first < envs.stop)]
        qpos0[t + 1, here // episodes] = q[here - envs.start]

    run_batch(agent, batch, steps, keep, advance, num_threads)
    out = AgentRun(key_of=key_of)
    for i, key in enumerate(keys):
        rows = slot[i * episodes:(i + 1) * episodes]
        if key[0].startswith("goal:"):
            out.dist[key] = dist[1:, rows].T
        else:
            out.obs[key] = obs[:, rows]
        out.qpos0[key] = qpos0[:, i]
        out.diverged[key] = dead[i * episodes:(i + 1) * episodes]
    return out


def judge_family(f: Family, run: AgentRun, start: str) -> dict[str, Any]:
    """Pass share and mean measures of one family from one start, for one agent's run."""
    from humanoid_env.tasks import GOALS, goal_obs

    if f.judge is not None:
        ok, measures = f.judge(Trace(run.find(run.obs, run.key_of[f.name], start)))
        diverged = run.find(run.diverged, run.key_of[f.name], start)
        return {"pass": float((ok & ~diverged).mean()), "diverged": int(diverged.sum()),
                **{k: float(np.mean(v)) for k, v in measures.items()}}
    poses = {}
    for g in GOALS:
        key = (f"goal:{g}", start)
        dist = run.dist[key] if key in run.dist else d_smpl(run.obs[("", start)][1:], goal_obs(g)).T
        poses[g] = {"success": float(goal_success(dist).mean()), "proximity": float(goal_proximity(dist).mean()),
                    "final_distance": float(dist[:, -1].mean())}
    success = float(np.mean([p["success"] for p in poses.values()]))
    return {"pass": success, "success": success, "proximity": float(np.mean([p["proximity"] for p in poses.values()])),
            "final_distance": float(np.mean([p["final_distance"] for p in poses.values()])), "poses": poses}


def estimate_env_steps(fams: Sequence[Family], episodes: int, steps: int, model: bool, refined: bool = False) -> int:
    """Env steps one agent simulates: every prompt of `plan` from each of its starts."""
    return sum(len(s) for s in plan(fams, model, refined)[0].values()) * episodes * steps


#: the floor agents a judged agent is held against, by the names `fbcpr.inference.agents.make_agent` knows
FLOORS = ("zero", "random")


def _goals_beyond_floors(poses: dict[str, dict[str, Any]], judged: str, floors: Sequence[str]) -> dict[str, Any]:
    """The goal family's score for the judged agent: the mean success over the poses, a pose counting only where
    the agent reaches it more often than every floor (standing still reaches the T-poses: the rest pose is one)."""
    mine = poses[judged]
    best = {g: max(poses[f][g]["success"] for f in floors) for g in mine}
    reached = [g for g, p in mine.items() if p["success"] >= PASS_SHARE]  # in half the episodes or more
    return {"poses_reached": reached,
            "reached_not_above_floors": [g for g in reached if mine[g]["success"] <= best[g]],
            "success_above_floors": float(np.mean([p["success"] if p["success"] > best[g] else 0.0
                                                   for g, p in mine.items()]))}


def check(agents: dict[str, Any], names: Sequence[str] | None = None, episodes: int = 8, steps: int = 300,
          seed: int = 0, out: Path | None = None, show_progress: bool = True,
          num_threads: int | None = None, refine: Refinement | None = None) -> dict[str, Any]:
    """Run the behaviour families for each agent (the first is the one judged; the others, usually the zero and
    random floors, stand beside it) from the same starts, and with `out` write behaviours.json and one contact
    sheet per family there. A family passes where the judged agent's score beats every floor among `agents` (named
    in `FLOORS`) by `MARGIN`. With `refine`, each family's task prompt is refined first (the goal poses' are not)."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from fbcpr.core.progress import progress_display
    from fbcpr.eval.runner import refined_prompts

    fams = families(names)
    if episodes < 1 or episodes * steps > MAX_EPISODE_STEPS:
        raise InputError(f"episodes x steps must be 1-{MAX_EPISODE_STEPS:,} (every step of every episode is kept to "
                         f"judge it; e.g. 32 episodes of 300 steps), got {episodes} x {steps}")
    if steps < MIN_STEPS:
        raise InputError(f"steps must be >= {MIN_STEPS} ({MIN_STEPS // CONTROL_HZ} s): the checks read the last "
                         f"half of an episode and its last second; got {steps}")
    starts = start_states(episodes, seed)
    columns = (TextColumn("{task.description:>8}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("eta"), TimeRemainingColumn())
    runs: dict[str, AgentRun] = {}
    with progress_display(Console(stderr=True), *columns, disable=not show_progress) as progress:
        for name, agent in agents.items():
            polish = refine if agent.z_dim > 0 else None
            tuning = progress.add_task("refine", total=refine_env_steps(fams, polish)) if polish else None
            bar = progress.add_task(name, total=estimate_env_steps(fams, episodes, steps, agent.z_dim > 0,
                                                                   polish is not None))

            def advance(k: int, bar: Any = bar) -> None:
                progress.advance(bar, k)

            def refined(k: int, tuning: Any = tuning) -> None:
                progress.advance(tuning, k * REFINE_STARTS)

            runs[name] = run_agent(agent, fams, starts, steps, advance, num_threads, polish, seed, refined)
    judged = next(iter(agents))
    results: dict[str, Any] = {"agent": judged, "episodes": episodes, "steps": steps, "seed": seed, "margin": MARGIN,
                               "refine": refine.generations if refine else 0,
                               "refined_prompts": sorted(refined_prompts(agents[judged]) & {f.prompt for f in fams}),
                               "families": {}}
    floors = [name for name in agents if name in FLOORS and name != judged]
    for f in fams:
        per_agent = {name: {s: judge_family(f, run, s) for s in f.starts} for name, run in runs.items()}
        scores = {name: a[f.start]["pass"] for name, a in per_agent.items()}
        entry: dict[str, Any] = {"prompt": f.prompt, "start": f.start, "rule": f.rule, "need": f.need,
                                 "agents": per_agent}
        if f.judge is None and floors:
            entry.update(_goals_beyond_floors({name: per_agent[name][f.start]["poses"] for name in agents}, judged,
                                              floors))
            scores[judged] = entry["success_above_floors"]
        entry["scores"] = scores
        entry["passed"] = beats_floors(scores[judged], [scores[n] for n in floors], f.need)
        results["families"][f.name] = entry
    passed = [n for n, e in results["families"].items() if e["passed"]]
    results["summary"] = {"passed": passed, "families_passed": len(passed), "of": len(fams)}
    if out is not None:
        results["sheets"] = write_sheets(fams, runs, out)
        from fbcpr.eval.runner import write_json

        write_json(results, out, "behaviours.json")
    return results


MIN_STEPS = 2 * CONTROL_HZ
#: goal poses shown on the goal family's contact sheet (one row each for the judged agent)
SHEET_POSES = ("t_pose", "hands_up", "kneel_both", "lie_back")
TILE = (224, 168)


def write_sheets(fams: Sequence[Family], runs: dict[str, AgentRun], out: Path, frames: int = 7) -> list[str] | str:
    """One PNG per family: a row per agent (the goal family: a row per pose in `SHEET_POSES` for the judged
    agent, then the floors), episode 0 from the family's own start, `frames` frames from start to end. Without an
    OpenGL renderer, says why instead."""
    from PIL import Image, ImageDraw

    from humanoid_env.model import load_model
    from humanoid_env.render import TrackRenderer

    try:
        renderer = TrackRenderer(load_model(), TILE[1], TILE[0])
    except RuntimeError as err:
        return f"no contact sheets: {err}"
    folder = out / "behaviours"
    folder.mkdir(parents=True, exist_ok=True)
    judged = next(iter(runs))
    written = []
    try:
        for f in fams:
            rows = []
            for name, run in runs.items():
                if f.judge is None:
                    prompts = [f"goal:{g}" for g in SHEET_POSES] if name == judged else [""]
                else:
                    prompts = [run.key_of[f.name]]
                for p in prompts:
                    key = (p, f.start) if (p, f.start) in run.qpos0 else ("", f.start)
                    label = f"{name}: {p if name == judged else 'floor'}, {f.start} start"
                    rows.append((label, run.qpos0[key]))
            sheet = Image.new("RGB", (TILE[0] * frames, (TILE[1] + 18) * len(rows)), (20, 20, 20))
            draw = ImageDraw.Draw(sheet)
            for r, (label, qpos) in enumerate(rows):
                y = r * (TILE[1] + 18)
                draw.text((4, y + 2), label, fill=(255, 255, 255))
                steps = np.linspace(0, len(qpos) - 1, frames).round().astype(int)
                for c, (t, image) in enumerate(zip(steps, renderer.render_qpos(qpos[steps]))):
                    tile = Image.fromarray(image)
                    ImageDraw.Draw(tile).text((4, 4), f"{t / CONTROL_HZ:.1f} s  pelvis {qpos[t, 2]:.2f} m",
                                              fill=(255, 255, 0))
                    sheet.paste(tile, (c * TILE[0], y + 18))
            path = folder / f"{f.name}.png"
            sheet.save(path)
            written.append(str(path))
    finally:
        renderer.close()
    return written


def table(results: dict[str, Any]) -> Any:
    """A rich table: each family's score from its own start for every agent, how far the judged agent is above the
    better floor, its share from the other start, and whether it passed."""
    from rich.table import Table

    agents = list(next(iter(results["families"].values()))["agents"])
    judged = results["agent"]
    refined = f", prompts refined by {results['refine']} generations" if results.get("refine") else ""
    if results.get("refined_prompts"):
        refined += f", stored prompts refined at export: {', '.join(results['refined_prompts'])}"
    t = Table(title=f"behaviour checks: {results['episodes']} episodes of {results['steps'] / CONTROL_HZ:g} s, "
                    f"seed {results['seed']}{refined}")
    t.add_column("family")
    t.add_column("start")
    for a in agents:
        t.add_column(a, justify="right")
    t.add_column("above floors", justify="right")
    t.add_column("other start", justify="right")
    t.add_column("passed")
    for name, e in results["families"].items():
        floors = [e["scores"][a] for a in agents if a in FLOORS and a != judged]
        above = f"{e['scores'][judged] - max(floors):+.2f}" if floors else "-"
        other = e["agents"][judged][OTHER_START[e["start"]]]["pass"]
        t.add_row(name, e["start"], *(f"{e['scores'][a]:.2f}" for a in agents), above, f"{other:.2f}",
                  "[green]yes[/]" if e["passed"] else "[red]no[/]")
    s = results["summary"]
    others = ", ".join(f"{o} beside {k}" for k, o in OTHER_START.items())
    t.caption = (f"{judged} passes {s['families_passed']} of {s['of']} families: a family needs 0.5 of its episodes "
                 f"(the goal poses 0.3 mean success, counting only poses reached more often than by every floor) "
                 f"and {results['margin']:g} more than each floor from the same start. Other start: {judged} from "
                 f"{others}")
    return t
