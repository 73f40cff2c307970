"""The benchmark runner: reward, goal and tracking episodes on the batched humanoid env (App. C.3).

Reward and goal episodes last 300 steps from the test initial distribution, a mixture of Fall states and
motion (MoCap) states; every task sees the same initial states. Tracking starts each clip's first state and
runs its length. Episodes of one task run as one batch of envs; an env whose simulation diverges stops
scoring (reward 0, goal distance infinite, tracking failed) for the rest of its episode.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from fbcpr.core.checkpoint import CheckpointError
from fbcpr.core.errors import InputError, PromptError
from fbcpr.core.progress import LineProgress, progress_display
from fbcpr.eval.agents import Actor, Agent, SingleTaskAgent, action_mapping
from fbcpr.eval.rollout import Step, rollout
from fbcpr.metrics import d_smpl, emd, goal_proximity, goal_success, imitation_scores, tracking_success
from humanoid_env.observation import OBS_DIM

SUITES = ("reward", "goal", "tracking")
#: What a prompt raises when a task cannot be asked of this agent (e.g. a reward that is zero on its whole buffer):
#: the task is skipped with the reason, the rest of the suite runs.
PROMPT_ERRORS: tuple[type[Exception], ...] = (PromptError, CheckpointError)
EPISODE_STEPS = 300
TEST_FALL_PROB = 0.5  # the paper mixes Fall and MoCap test states without giving the ratio; we use half-half


def _batch_z(z: np.ndarray, n: int) -> np.ndarray:
    z = np.asarray(z, dtype=np.float32)
    if z.ndim != 1:
        raise InputError(f"a prompt must return one z vector (d,), got shape {z.shape}")
    return np.broadcast_to(z, (n, z.shape[0])).copy()


class Rollouts:
    """One batched env reused for every task of a suite (and by prompt refinement for its candidates)."""

    def __init__(self, agent: Actor, num_envs: int, steps: int, num_threads: int | None) -> None:
        from humanoid_env.vector import VectorHumanoidEnv

        self.env = VectorHumanoidEnv(num_envs, max_episode_steps=steps, num_threads=num_threads,
                                     action_mapping=action_mapping(agent))
        self.num_envs, self.steps = num_envs, steps

    def run(self, agent: Actor, z_at: Callable[[int], np.ndarray], qpos: np.ndarray, qvel: np.ndarray,
            on_step: Callable[[int, dict[str, Any], np.ndarray], None], advance: Callable[[], None],
            on_start: Callable[[np.ndarray], None] | None = None) -> None:
        """Roll out from (qpos, qvel); `on_start(obs)` sees the first observations, `on_step(t, info, alive)` every
        next state, in the step's `info["final_obs"]`, `info["final_qpos"]` and `info["final_qvel"]`."""
        obs, _ = self.env.reset(options={"qpos": qpos, "qvel": qvel})
        if on_start is not None:
            on_start(obs)
        alive = np.ones(self.num_envs, bool)

        def watch(step: Step) -> None:
            alive[step.info["diverged"]] = False
            on_step(step.t, step.info, alive)
            advance()

        rollout(self.env, obs, lambda t, o: np.asarray(agent.act(o, z_at(t), mean=True), dtype=np.float32),
                self.steps, watch)

    def close(self) -> None:
        self.env.close()


class Report:
    """Where results go as each task finishes: a task that cannot be prompted is skipped with its reason, and
    with an `out` folder results.json is rewritten after every task, so an interrupted run keeps what is done."""

    def __init__(self, results: dict[str, Any] | None = None, out: Path | None = None) -> None:
        self.results = results if results is not None else {}
        self.out = out

    def result(self, suite: str, name: str, entry: dict[str, Any]) -> None:
        self.results.setdefault(suite, {})[name] = entry
        self._flush()

    def skip(self, suite: str, name: str, reason: str) -> None:
        self.results.setdefault("skipped", {})[f"{suite}/{name}"] = reason
        self._flush()

    def _flush(self) -> None:
        if self.out is not None:
            write_json(self.results, self.out)


def _prompt(report: Report, suite: str, name: str, make_z: Callable[[], np.ndarray]) -> np.ndarray | None:
    """The task's z, or None after recording why it cannot be prompted."""
    try:
        return make_z()
    except PROMPT_ERRORS as err:
        report.skip(suite, name, str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__)
        return None


def refined_prompts(agent: Agent) -> set[str]:
    """Named tasks whose stored prompt the agent's checkpoint refined by rollouts (`fbcpr export --refine-prompts`):
    results mark them, since those z's are not zero-shot."""
    prompts = getattr(agent, "reward_prompts", None)
    return set(getattr(prompts, "refined", {}))


def _initial_states(episodes: int, fall_prob: float, motions: Any, seed: int) -> tuple[np.ndarray, np.ndarray]:
    from humanoid_env.inits import make_init

    return make_init(fall_prob, motions).sample(np.random.default_rng(seed), episodes)


def reward_suite(agent: Agent, tasks: Sequence[str], episodes: int, init: tuple[np.ndarray, np.ndarray],
                 progress: Progress | LineProgress, steps: int = EPISODE_STEPS, num_threads: int | None = None,
                 report: Report | None = None) -> dict[str, Any]:
    """Mean and std of the undiscounted return of each reward task (tasks it cannot prompt go to `report`)."""
    report = report if report is not None else Report()
    from humanoid_env.tasks import get_reward, task_category

    fns = [get_reward(t) for t in tasks]  # fail on a bad name before any simulation
    refined = refined_prompts(agent)
    bar = progress.add_task("reward", total=len(tasks) * steps)
    roll = Rollouts(agent, episodes, steps, num_threads)
    out: dict[str, Any] = {}
    try:
        for task, fn in zip(tasks, fns):
            z1 = _prompt(report, "reward", task, lambda: agent.reward_z(task))
            if z1 is None:
                progress.advance(bar, steps)
                continue
            z = _batch_z(z1, episodes)
            ret = np.zeros(episodes)

            def score(t: int, info: dict[str, Any], alive: np.ndarray) -> None:
                ret[:] += np.where(alive, fn(info["final_obs"]), 0.0)

            roll.run(agent, lambda t: z, *init, score, lambda: progress.advance(bar))
            out[task] = {"category": task_category(task), "return_mean": float(ret.mean()),
                         "return_std": float(ret.std()), "returns": ret.tolist(),
                         "prompt": "refined" if task in refined else "zero-shot"}
            report.result("reward", task, out[task])
    finally:
        roll.close()
    return out


def goal_suite(agent: Agent, goals: Sequence[str], episodes: int, init: tuple[np.ndarray, np.ndarray],
               progress: Progress | LineProgress, steps: int = EPISODE_STEPS, num_threads: int | None = None,
               report: Report | None = None) -> dict[str, Any]:
    """Success rate and proximity of each named goal pose (poses it cannot prompt go to `report`)."""
    report = report if report is not None else Report()
    from humanoid_env.tasks import goal_obs

    targets = [goal_obs(g) for g in goals]
    bar = progress.add_task("goal", total=len(goals) * steps)
    roll = Rollouts(agent, episodes, steps, num_threads)
    out: dict[str, Any] = {}
    try:
        for name, goal in zip(goals, targets):
            z1 = _prompt(report, "goal", name, lambda: agent.goal_z(goal))
            if z1 is None:
                progress.advance(bar, steps)
                continue
            z = _batch_z(z1, episodes)
            dist = np.empty((episodes, steps))

            def measure(t: int, info: dict[str, Any], alive: np.ndarray) -> None:
                dist[:, t] = np.where(alive, d_smpl(info["final_obs"], goal), np.inf)

            roll.run(agent, lambda t: z, *init, measure, lambda: progress.advance(bar))
            finite = np.where(np.isfinite(dist), dist, np.nan)
            out[name] = {"success": float(goal_success(dist).mean()), "proximity": float(goal_proximity(dist).mean()),
                         "min_distance": float(np.nanmin(finite)) if np.isfinite(dist).any() else float("inf")}
            report.result("goal", name, out[name])
    finally:
        roll.close()
    return out


def hold_first_pose(clip: Any) -> np.ndarray:
    """(T, 358) observations of a body frozen in the clip's first pose (its first qpos, at rest, every step): the
    tracking floor, since a trajectory no closer than this tracks nothing the clip does after its first frame."""
    from humanoid_env.model import load_model
    from humanoid_env.observation import observe

    frozen = observe(load_model(), clip.qpos[:1], np.zeros_like(clip.qvel[:1]))
    return np.repeat(frozen, clip.n_frames, axis=0)


def hold_first_pose_emd(clip: Any) -> float:
    """The EMD of the first-pose floor (`hold_first_pose`) to the clip."""
    return emd(hold_first_pose(clip), clip.obs)


def tracking_suite(agent: Agent, clips: Sequence[Any], progress: Progress | LineProgress, batch: int = 32,
                   num_threads: int | None = None, report: Report | None = None,
                   imitation: bool = False) -> dict[str, Any]:
    """Tracking success (d_smpl <= 0.5 at every step) and EMD for each clip, from its first state (clips it
    cannot prompt go to `report`); with `imitation`, also NEAR's DTW pose error and SPARC (next to the clip's
    own) of the same rollouts."""
    report = report if report is not None else Report()
    out: dict[str, Any] = {}
    bar = progress.add_task("tracking", total=sum(c.n_frames - 1 for c in clips))
    for start in range(0, len(clips), batch):
        prompted = [(c, _prompt(report, "tracking", c.name, lambda: agent.track_z(c.obs)))
                    for c in clips[start:start + batch]]
        for c, z in prompted:
            if z is None:
                progress.advance(bar, c.n_frames - 1)
        group = [c for c, z in prompted if z is not None]
        if not group:
            continue
        steps = max(c.n_frames for c in group) - 1
        zs = [np.asarray(z, dtype=np.float32) for _, z in prompted if z is not None]
        for c, z in zip(group, zs):
            if z.ndim != 2 or len(z) < 1:
                raise InputError(f"track_z for clip {c.name!r} must return (T, d) latents, got shape {z.shape}")
        traj = np.empty((len(group), steps + 1, OBS_DIM), np.float32)
        traj[:, 0] = [c.obs[0] for c in group]
        dead = np.zeros(len(group), bool)
        lengths = np.array([c.n_frames - 1 for c in group])

        def z_at(t: int) -> np.ndarray:
            return np.stack([z[min(t, len(z) - 1)] for z in zs])

        def record(t: int, info: dict[str, Any], alive: np.ndarray) -> None:
            traj[:, t + 1] = info["final_obs"]
            dead[:] |= ~alive & (t < lengths)

        roll = Rollouts(agent, len(group), steps, num_threads)
        try:
            qpos = np.stack([c.qpos[0] for c in group])
            qvel = np.stack([c.qvel[0] for c in group])
            roll.run(agent, z_at, qpos, qvel, record, lambda: None)
        finally:
            roll.close()
        for i, c in enumerate(group):
            agent_traj = traj[i, :c.n_frames]
            out[c.name] = {"success": float(tracking_success(agent_traj, c.obs) and not dead[i]),
                           "emd": emd(agent_traj, c.obs), "emd_hold_first_pose": hold_first_pose_emd(c),
                           "frames": c.n_frames}
            if imitation:
                out[c.name].update(imitation_scores(agent_traj, c.obs))
            report.result("tracking", c.name, out[c.name])
            progress.advance(bar, c.n_frames - 1)
    return out


def _split_names(names: Iterable[str], motions: Any, wanted: Sequence[str]) -> dict[str, list[str]]:
    """Sort user-given names into the suite they belong to: goal poses, clip names, else reward tasks."""
    from humanoid_env.tasks import GOALS, get_reward

    clips = set(motions.names) if motions is not None else set()
    groups: dict[str, list[str]] = {s: [] for s in SUITES}
    for n in names:
        if n in GOALS:
            suite = "goal"
        elif n in clips:
            suite = "tracking"
        else:
            try:
                get_reward(n)
            except ValueError as err:
                raise InputError(f"{n!r} is neither a goal pose, a clip of the motions nor a reward task "
                                 f"({err})") from None
            suite = "reward"
        if suite not in wanted:
            raise InputError(f"{n!r} is a {suite} task, but the suite being run is {', '.join(wanted)}")
        groups[suite].append(n)
    return groups


def evaluate(agent: Agent, suite: str = "all", tasks: Sequence[str] | None = None, episodes: int = 10,
             motions: Any = None, out: str | Path | None = None, steps: int = EPISODE_STEPS,
             fall_prob: float = TEST_FALL_PROB, seed: int = 0, num_threads: int | None = None,
             show_progress: bool = True, agent_name: str | None = None) -> dict[str, Any]:
    """Run one suite ("reward", "goal", "tracking") or "all" and return the results dict.

    `tasks` restricts each suite to the given names (reward task names, goal pose names, clip names);
    `motions` is a MotionLibrary: its states join the test initial distribution and its clips are tracked.
    With `out`, writes results.json and plots there.
    """
    from humanoid_env.tasks import GOALS, TASKS

    if suite not in (*SUITES, "all"):
        raise InputError(f"unknown suite {suite!r}: choose one of {', '.join(SUITES)} or all")
    if episodes < 1 or steps < 1:
        raise InputError(f"episodes and steps must be >= 1, got {episodes} and {steps}")
    wanted = SUITES if suite == "all" else (suite,)
    if "tracking" in wanted and motions is None:
        raise InputError("the tracking suite needs motions (a MotionLibrary)")
    clip_names = list(motions.names) if motions is not None else []
    # a single-task agent is evaluated on its own task: its reward, or the clips it imitates
    single = agent if isinstance(agent, SingleTaskAgent) else None
    imitation = single is not None and single.imitation is not None
    if tasks:
        chosen = _split_names(tasks, motions, wanted)
    elif single is not None:
        chosen = {"reward": [single.task] if single.task else [], "goal": [],
                  "tracking": clip_names if imitation else []}
    else:
        chosen = {"reward": list(TASKS), "goal": list(GOALS), "tracking": clip_names}
    results: dict[str, Any] = {"agent": agent_name or getattr(agent, "name", type(agent).__name__),
                               "episodes": episodes, "steps": steps, "fall_prob": fall_prob, "seed": seed,
                               "complete": False}
    report = Report(results, Path(out) if out is not None else None)
    init = _initial_states(episodes, fall_prob, motions, seed) if {"reward", "goal"} & set(wanted) else None
    columns = (TextColumn("{task.description:>8}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("eta"), TimeRemainingColumn())
    with progress_display(Console(), *columns, disable=not show_progress) as progress:
        if show_progress:
            progress.console.print(plan(chosen, wanted, episodes, steps, motions), highlight=False)
        if "reward" in wanted and chosen["reward"]:
            assert init is not None  # drawn above for the reward and goal suites
            reward_suite(agent, chosen["reward"], episodes, init, progress, steps, num_threads, report)
        if "goal" in wanted and chosen["goal"]:
            assert init is not None
            goal_suite(agent, chosen["goal"], episodes, init, progress, steps, num_threads, report)
        if "tracking" in wanted and chosen["tracking"]:
            by_name = {c.name: c for c in motions.clips}
            tracking_suite(agent, [by_name[n] for n in chosen["tracking"]], progress, num_threads=num_threads,
                           report=report, imitation=imitation)
    from fbcpr.eval.report import summarize

    results["summary"] = summarize(results)
    results["complete"] = True
    if out is not None:
        write_results(results, Path(out))
    return results


#: Seconds per step of a batch of E episodes on 2 CPU cores, about STEP_S[0] + STEP_S[1] * E (the policy and the
#: simulation, measured with the shipped model: 10 episodes of 300 steps of every task take about 40 minutes),
#: and per tracked clip (its EMD).
STEP_S = (0.003, 0.009)
CLIP_S = 0.5


def estimate_seconds(chosen: dict[str, list[str]], wanted: Sequence[str], episodes: int, steps: int,
                     motions: Any) -> float:
    """About how long a run takes on 2 CPU cores: each reward or goal task is `steps` batched steps of `episodes`
    envs; the clips are tracked in one batch as long as the longest."""
    seconds = 0.0
    for suite in ("reward", "goal"):
        if suite in wanted:
            seconds += len(chosen[suite]) * steps * (STEP_S[0] + STEP_S[1] * episodes)
    if "tracking" in wanted and chosen["tracking"]:
        frames = {c.name: c.n_frames - 1 for c in motions.clips}
        n = len(chosen["tracking"])
        longest = max(frames[name] for name in chosen["tracking"])
        seconds += longest * (STEP_S[0] + STEP_S[1] * min(n, 32)) * -(-n // 32) + CLIP_S * n
    return seconds


def plan(chosen: dict[str, list[str]], wanted: Sequence[str], episodes: int, steps: int, motions: Any) -> str:
    """What a run will simulate and about how long it takes, said before it starts: tasks x episodes x steps, and
    the clips to track."""
    parts, total = [], 0
    for suite, what in (("reward", "reward tasks"), ("goal", "goal poses")):
        if suite in wanted and chosen[suite]:
            parts.append(f"{len(chosen[suite])} {what} x {episodes} episodes x {steps} steps")
            total += len(chosen[suite]) * episodes * steps
    if "tracking" in wanted and chosen["tracking"]:
        frames = {c.name: c.n_frames - 1 for c in motions.clips}
        parts.append(f"{len(chosen['tracking'])} clips to track")
        total += sum(frames[n] for n in chosen["tracking"])
    minutes = estimate_seconds(chosen, wanted, episodes, steps, motions) / 60.0
    took = "under a minute" if minutes < 1 else f"about {minutes:.0f} minute{'s' if round(minutes) > 1 else ''}"
    return f"evaluating {', '.join(parts) or 'nothing'}: {total:,} env steps, {took} on 2 CPU cores"


def write_results(results: dict[str, Any], out: Path) -> list[Path]:
    """results.json plus bar-chart PNGs; returns the written paths."""
    from fbcpr.eval.report import plot_results

    return [write_json(results, out), *plot_results(results, out)]


def write_json(results: dict[str, Any], out: Path, name: str = "results.json") -> Path:
    """`name` under `out`, replaced atomically (also the partial results of a run still going)."""
    from fbcpr.eval.report import json_safe

    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(json_safe(results), indent=2, allow_nan=False))
    tmp.replace(path)
    return path
