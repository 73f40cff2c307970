"""`fbcpr prompt`, `fbcpr track`, `fbcpr timeline`: prompt a checkpoint zero-shot, roll it out, print metrics,
optionally write a video (side by side with the reference for tracking)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import typer
from rich.table import Table

from fbcpr.cli.common import (
    MODEL_HELP,
    choose_model,
    cli_errors,
    comma_ints,
    console,
    err_console,
    model_and,
    progress,
)
from fbcpr.eval.rollout import Step
from fbcpr.eval.rollout import rollout as step_through


@dataclass
class Episode:
    """What one rollout visited: states[0] is the start; `diverged_at` is the step the simulation blew up."""

    obs: list[np.ndarray] = field(default_factory=list)
    qpos: list[np.ndarray] = field(default_factory=list)
    qvel: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)
    diverged_at: int | None = None

    @property
    def steps(self) -> int:
        return len(self.actions)

    def rewards(self, task: str) -> np.ndarray:
        """(steps,) reward of a task on every next state."""
        from humanoid_env.tasks import get_reward

        if not self.actions:
            return np.zeros(0)
        obs, qpos, qvel = np.stack(self.obs[1:]), np.stack(self.qpos[1:]), np.stack(self.qvel[1:])
        return np.asarray(get_reward(task)(obs, np.stack(self.actions), qpos, qvel), dtype=np.float64)


def require_renderer() -> None:
    """Fail before any simulation when a video is asked for but no OpenGL backend works."""
    from humanoid_env.render import renderer_available

    if not renderer_available():
        raise RuntimeError("cannot write a video: no offscreen renderer (set MUJOCO_GL=egl or MUJOCO_GL=osmesa)")


def rollout(bfm: Any, zs: np.ndarray, seed: int = 0, start: tuple[np.ndarray, np.ndarray] | None = None,
            video: bool = False, reference: Any = None, label: str = "rollout") -> Episode:
    """Run the policy for len(zs) steps with z = zs[t] at step t; frames (agent | reference) when `video`."""
    from fbcpr.eval.agents import action_mapping
    from humanoid_env.env import HumanoidEnv

    steps = len(zs)
    env = HumanoidEnv(max_episode_steps=max(steps, 1), render_mode="rgb_array" if video else None,
                      action_mapping=action_mapping(bfm))
    ref_frame = _reference_renderer(env, reference) if video and reference is not None else None
    ep = Episode()
    try:
        options = {"qpos": start[0], "qvel": start[1]} if start is not None else None
        obs, info = env.reset(seed=seed, options=options)

        def record(o: np.ndarray, inf: dict, t: int) -> None:
            ep.obs.append(o)
            ep.qpos.append(inf["qpos"])
            ep.qvel.append(inf["qvel"])
            if video:
                frame = env.render()
                assert frame is not None  # an rgb_array env renders a frame
                ep.frames.append(frame if ref_frame is None else side_by_side(frame, ref_frame(t)))

        record(obs, info, 0)
        with progress() as bar:
            task = bar.add_task(f"{label}, rendering" if video else label, total=steps)

            def watch(step: Step) -> bool:
                ep.actions.append(np.asarray(step.action, dtype=np.float32))
                record(step.obs, step.info, step.t + 1)
                bar.advance(task)
                if step.info["diverged"]:
                    ep.diverged_at = step.t
                return bool(step.info["diverged"])

            step_through(env, obs, lambda t, o: bfm.act(o, zs[t]), steps, watch)
    finally:
        env.close()
    return ep


def _reference_renderer(env: Any, clip: Any) -> Any:
    """frame(t) of the reference clip's pose at step t (clamped to its last frame), same camera and size."""
    from humanoid_env.render import TrackRenderer

    renderer = TrackRenderer(env.model, *env._size)

    def frame(t: int) -> np.ndarray:
        i = min(t, clip.n_frames - 1)
        return renderer.render_qpos(clip.qpos[i:i + 1])[0]

    return frame


def caption(frame: np.ndarray, text: str) -> np.ndarray:
    """The frame with `text` in its top-left corner (Pillow ships with matplotlib and imageio)."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(frame)
    draw = ImageDraw.Draw(img)
    draw.rectangle((0, 0, 8 + 7 * len(text), 18), fill=(0, 0, 0))
    draw.text((4, 3), text, fill=(255, 255, 255))
    return np.asarray(img)


def side_by_side(agent: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """One tracking video frame: the agent left, the reference right, each labelled."""
    return np.concatenate([caption(agent, "agent"), caption(reference, "reference")], axis=1)


def write_frames(ep: Episode, path: Path) -> None:
    from humanoid_env.render import write_video

    err_console.print(f"encoding {len(ep.frames)} frames into {path}", highlight=False)
    write_video(ep.frames, path, fps=30)
    console.print(f"video written to [bold]{path}[/]")


def _refine(bfm: Any, z0: np.ndarray, target: Any, steps: int, seed: int, generations: int, population: int,
            n_starts: int) -> Any:
    """z0 refined by rollouts from standing starts drawn with seed + 1 (apart from the shown episode's start)."""
    from fbcpr.inference.refine import Search, goal_objective, refine, reward_objective, standing_starts

    search = Search(generations=generations, population=population, seed=seed)
    objective = reward_objective(target) if isinstance(target, str) else goal_objective(target)
    starts = standing_starts(n_starts, seed + 1)
    with progress() as bar:
        task = bar.add_task("refine", total=(search.generations * search.population + 1) * steps)
        return refine(bfm, z0, objective, starts, steps=steps, search=search,
                      on_step=lambda k: bar.advance(task, k))


def _load(ckpt: str, device: str) -> Any:
    from fbcpr.inference.bfm import BFM

    return BFM.load(ckpt, device=device)


def _load_clip(spec: str) -> Any:
    from fbcpr.inference.prompt import load_motion

    return load_motion(spec)


def _table(title: str, rows: list[tuple[str, str]]) -> Table:
    table = Table(title=title, show_header=False)
    table.add_column("metric", style="bold")
    table.add_column("value", justify="right")
    for k, v in rows:
        table.add_row(k, v)
    return table


def _diverged_row(ep: Episode) -> list[tuple[str, str]]:
    return [("simulation diverged at step", str(ep.diverged_at))] if ep.diverged_at is not None else []


CKPT_HELP = "The model (as --model; default: the shipped pretrained model). " + MODEL_HELP
DEVICE = "<cpu|cuda[:i]>"
VIDEO_HELP = "Write an .mp4 of the rollout here (needs an OpenGL backend)."


@cli_errors
def prompt_command(
    ckpt: str | None = typer.Argument(None, metavar="CKPT", help=CKPT_HELP, show_default=False),
    model: str | None = typer.Option(None, "--model", help=MODEL_HELP),
    reward: str | None = typer.Option(None, "--reward", help="Reward task, e.g. jump-2 or move-ego-0-2*raisearms-h-h "
                                         "(`fbcpr tasks` lists them)."),
    goal: str | None = typer.Option(None, "--goal", help="Goal pose name, e.g. t_pose (`fbcpr tasks` lists them)."),
    imitate: str | None = typer.Option(None, "--imitate", help="Clip .npz (or built-in clip name, e.g. walk) to "
                                          "imitate with one z (ER_FB)."),
    steps: int = typer.Option(300, "--steps", min=1, help="Episode length in control steps (30 Hz)."),
    video: Path | None = typer.Option(None, "--video", help=VIDEO_HELP),
    seed: int = typer.Option(0, "--seed", help="Seed of the initial state."),
    method: Literal["weighted", "regression", "backward", "states", "mix"] | None = typer.Option(
        None, "--method", help="With --reward: reward inference, weighted (paper, the default) or regression. With "
                               "--goal: backward (z = B(g), paper, the default), states (the goal as a reward on "
                               "visited states) or mix."),
    device: str = typer.Option("cpu", "--device", metavar=DEVICE, help="torch device."),
    refine: int = typer.Option(0, "--refine", min=0, help="With --reward or --goal: improve the inferred z by this "
                               "many generations of rollouts (cross-entropy search on the z sphere, weights "
                               "untouched); ~20 s a generation on 2 cores at the defaults. 0: zero-shot."),
    refine_starts: int = typer.Option(8, "--refine-starts", min=1, help="Standing starts each candidate z is "
                                      "rolled out from (drawn apart from the --seed start)."),
    refine_population: int = typer.Option(16, "--refine-population", min=2, help="z's rolled out per generation."),
    save_z: Path | None = typer.Option(None, "--save-z", help="Write the prompt's z here (.npy), e.g. to pass "
                                          "to BFM.act."),
) -> None:
    """Prompt a model with one reward, goal or clip, roll it out and print return and metrics (`fbcpr tasks` lists
    the reward tasks and goal poses)."""
    from fbcpr.inference.prompt import goal_observation
    from fbcpr.metrics import d_smpl, emd, goal_proximity, goal_success

    given = [x for x in (reward, goal, imitate) if x is not None]
    if len(given) != 1:
        raise typer.BadParameter("give exactly one of --reward, --goal or --imitate")
    if method is not None and imitate is not None:
        raise typer.BadParameter("--method chooses how a reward or a goal is inferred: it does not apply to --imitate")
    if refine and imitate is not None:
        raise typer.BadParameter("--refine applies to --reward and --goal: a clip has no objective to search on")
    if video is not None:
        require_renderer()
    if save_z is not None:
        from fbcpr.core.paths import check_output_file

        check_output_file(save_z, "--save-z")
    bfm = _load(choose_model(ckpt, model), device)
    clip = None
    if reward is not None:
        z, title = bfm.prompt.reward(reward, method=method or "weighted"), f"reward {reward}"
    elif goal is not None:
        z, title = bfm.prompt.goal(goal, method=method or "backward"), f"goal {goal}"
        target = goal_observation(goal, bfm.obs_dim)[0]
    else:
        assert imitate is not None  # exactly one of the three was given
        clip = _load_clip(imitate)
        z, title = bfm.prompt.imitate(clip), f"imitate {clip.name}"
    refined = None
    if refine:
        refined = _refine(bfm, z, reward if reward is not None else target, steps, seed, refine,
                          refine_population, refine_starts)
        z, title = refined.z, f"{title} (refined)"
    if save_z is not None:
        np.save(save_z, np.asarray(z, dtype=np.float32))
        console.print(f"z written to [bold]{save_z}[/]")
    ep = rollout(bfm, np.repeat(z[None], steps, 0), seed=seed, video=video is not None, label=title)
    rows = [("steps", str(ep.steps))]
    if reward is not None:
        r = ep.rewards(reward)
        stored = bfm.prompt.stored_reward(reward, method=method or "weighted")
        source = (f"stored at export (from {bfm.reward_prompts.states:,} states)" if stored is not None
                  else "inferred from the checkpoint's reward states")
        record = bfm.reward_prompts.refined.get(reward.strip()) if stored is not None else None
        if record is not None:
            source += (f", refined by {record['generations']} generations of rollouts (mean reward "
                       f"{record['score0']:.3f} -> {record['score']:.3f})")
        rows += [("return", f"{r.sum():.2f}"), ("mean reward", f"{r.mean() if len(r) else 0.0:.3f}"),
                 ("reward prompt", source)]
    elif goal is not None:
        dist = d_smpl(np.stack(ep.obs[1:]), target) if ep.steps else np.full(1, np.inf)
        rows += [("final d_smpl", f"{dist[-1]:.3f}"), ("min d_smpl", f"{dist.min():.3f}"),
                 ("reached (d <= 2 at any step)", "yes" if goal_success(dist) else "no"),
                 ("proximity", f"{goal_proximity(dist):.3f}")]
    else:
        assert clip is not None  # loaded above for --imitate
        rows += [("EMD to clip", f"{emd(np.stack(ep.obs), clip.obs):.3f}")]
    if refined is not None:
        rows += [("refinement starts: score z0 -> z", f"{refined.score0:.3f} -> {refined.score:.3f}"),
                 ("refinement: episodes, cos(z, z0)", f"{refined.episodes}, {refined.cosine:.3f}")]
    console.print(_table(title, rows + _diverged_row(ep)))
    if video is not None:
        write_frames(ep, video)


@cli_errors
def track_command(
    args: list[str] = typer.Argument(..., metavar="[CKPT] CLIP", show_default=False,
                                     help="The clip .npz (or built-in clip name, e.g. walk) to track from its first "
                                          "state, after an optional CKPT: " + MODEL_HELP),
    model: str | None = typer.Option(None, "--model", help=MODEL_HELP),
    video: Path | None = typer.Option(None, "--video", help=VIDEO_HELP + " Agent left, reference right, labelled."),
    device: str = typer.Option("cpu", "--device", metavar=DEVICE, help="torch device."),
    refine: int = typer.Option(0, "--refine", min=0, help="Refine the z's by a receding-horizon search with the "
                               "simulator, this many candidate z's a round (one batch of envs); 0: zero-shot. The "
                               "cost is printed as seconds of compute per second of motion."),
    rounds: int = typer.Option(3, "--refine-rounds", min=1, help="Search rounds per window, each narrowing around "
                               "the best candidates of the last."),
    window: int = typer.Option(8, "--refine-window", min=1, help="Steps executed per window before searching again."),
    horizon: int = typer.Option(24, "--refine-horizon", min=1, help="Steps each candidate is rolled out and scored "
                                "(at least the window: it judges where a candidate leaves the body)."),
    position_weight: float = typer.Option(0.0, "--refine-position-weight", min=0.0,
                                          help="Weight of the per-step body-position error (metres) added to the "
                                               "search's d_smpl cost."),
    leads: str | None = typer.Option(None, "--refine-leads", metavar="K,...",
                                     help="Also start each window's search from the B-given z's this many steps "
                                          "ahead (comma-separated, e.g. 2,4,8: for a body that lags the clip)."),
    lookaheads: str | None = typer.Option(None, "--refine-lookaheads", metavar="L,...",
                                          help="And from the B-given z's of these lookahead lengths "
                                               "(comma-separated, e.g. 1,2,4,16)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the search's candidate draws."),
) -> None:
    """Track a clip with one z per step and print tracking success (d_smpl <= 0.5 throughout), EMD and the
    per-joint position error, next to a body frozen in the clip's first pose.

    CKPT is a BFM (z's from ER_FB of the next states) or an NPMP checkpoint (z's from its encoder); --refine needs
    a BFM."""
    from fbcpr.eval.runner import hold_first_pose
    from fbcpr.inference.bfm import BFM
    from fbcpr.inference.track_refine import Receding
    from fbcpr.metrics import d_smpl, emd, mpjpe, tracking_success

    ckpt, clip_path = model_and(args, "CLIP")
    settings = Receding(candidates=refine, rounds=rounds, window=window, horizon=horizon, seed=seed,
                        position_weight=position_weight, leads=comma_ints(leads, "--refine-leads"),
                        lookaheads=comma_ints(lookaheads, "--refine-lookaheads"))
    if refine:
        settings.check()  # before any model is loaded or frame simulated
    if video is not None:
        require_renderer()
    from fbcpr.inference.agents import load_tracker

    clip = _load_clip(clip_path)
    agent = load_tracker(choose_model(ckpt, model), device)  # a BFM (ER_FB latents) or an NPMP (its encoder's latents)
    title = f"track {clip.name}" + (" (refined)" if refine else "")
    refined = None
    if refine:
        if not isinstance(agent, BFM):
            raise typer.BadParameter("--refine searches a BFM's z's; this checkpoint is not a BFM")
        with progress() as bar:
            task = bar.add_task("refine, windows", total=-(-(clip.n_frames - 1) // window))
            refined = agent.prompt.track_refined(clip, settings,
                                                 on_window=lambda done, total: bar.update(task, completed=done))
        ep = Episode(obs=list(refined.obs), qpos=list(refined.qpos), qvel=list(refined.qvel),
                     diverged_at=refined.diverged_at)
        if video is not None:
            ep.frames = replay_frames(refined.qpos, refined.qvel, clip)
    else:
        ep = rollout(agent, agent.track_z(clip), start=(clip.qpos[0], clip.qvel[0]), video=video is not None,
                     reference=clip, label=title)
    states = np.stack(ep.obs)
    ref, floor = clip.obs[: len(states)], hold_first_pose(clip)
    success = ep.diverged_at is None and len(states) == clip.n_frames and tracking_success(states, ref)
    rows = [("frames", f"{len(states)} / {clip.n_frames}"), ("tracking success", "yes" if success else "no"),
            ("EMD", f"{emd(states, clip.obs):.3f}"),
            ("EMD, body frozen in the first pose", f"{emd(floor, clip.obs):.3f}"),
            ("MPJPE, pelvis-relative (m)", f"{mpjpe(states, ref):.3f}"),
            ("MPJPE, body frozen in the first pose", f"{mpjpe(floor[: len(states)], ref):.3f}"),
            ("mean d_smpl", f"{d_smpl(states, ref).mean():.3f}")]
    if refined is not None:
        rows += [("planning cost, B-given -> kept (mean d_smpl)",
                  f"{refined.plan_cost0.mean():.3f} -> {refined.plan_cost.mean():.3f}")]
    console.print(_table(title, rows + _diverged_row(ep)))
    if refined is not None:
        console.print(f"refinement cost: {refined.seconds:.1f} s of compute for {refined.motion_seconds:.1f} s of "
                      f"motion, {refined.cost:.1f} s per second of motion ({refined.cpu_cost:.1f} s of processor "
                      f"time per second; {refine} candidates x {rounds} rounds, horizon {horizon}, window {window}, "
                      f"{refined.rollouts} rollouts)", highlight=False)
    if video is not None:
        write_frames(ep, video)


def replay_frames(qpos: np.ndarray, qvel: np.ndarray, clip: Any) -> list[np.ndarray]:
    """Tracking video frames of states already simulated (agent | reference), rendered without stepping again."""
    from types import SimpleNamespace

    from humanoid_env.env import HumanoidEnv

    env = HumanoidEnv(render_mode="rgb_array")
    try:
        agent = _reference_renderer(env, SimpleNamespace(qpos=qpos, qvel=qvel, n_frames=len(qpos)))
        reference = _reference_renderer(env, clip)
        return [side_by_side(agent(t), reference(t)) for t in range(len(qpos))]
    finally:
        env.close()


@cli_errors
def timeline_command(
    args: list[str] = typer.Argument(..., metavar="[CKPT] SPEC", show_default=False,
                                     help='Segments "ITEM:SECONDS,..." after an optional CKPT; ITEM is a reward task, '
                                          'a goal name, a clip .npz or a built-in clip name, e.g. '
                                          '"move-ego-0-2:4,crouch-0:2,sitonground:4". CKPT: ' + MODEL_HELP),
    model: str | None = typer.Option(None, "--model", help=MODEL_HELP),
    video: Path | None = typer.Option(None, "--video", help=VIDEO_HELP),
    seed: int = typer.Option(0, "--seed", help="Seed of the initial state."),
    device: str = typer.Option("cpu", "--device", metavar=DEVICE, help="torch device."),
) -> None:
    """Play prompts back to back (walk, then jump, then sit...) and print a per-segment summary."""
    from fbcpr.inference.timeline import Timeline

    ckpt, spec = model_and(args, "SPEC")
    if video is not None:
        require_renderer()
    bfm = _load(choose_model(ckpt, model), device)
    timeline = Timeline.from_string(bfm.prompt, spec)
    ep = rollout(bfm, timeline.z_per_step(), seed=seed, video=video is not None, label="timeline")
    console.print(timeline_table(timeline, ep))
    if ep.diverged_at is not None:
        console.print(f"[yellow]simulation diverged at step {ep.diverged_at}[/]")
    if video is not None:
        seg = timeline.segment_index()
        # frame t shows the state reached by step t-1's action, taken under that step's prompt
        labels = [timeline.segments[seg[max(t - 1, 0)]].label for t in range(len(ep.frames))]
        ep.frames = [caption(f, Path(label).stem if label.endswith(".npz") else label)
                     for f, label in zip(ep.frames, labels)]
        write_frames(ep, video)


def timeline_table(timeline: Any, ep: Episode) -> Table:
    """Per segment: mean reward (reward tasks), final d_smpl (goals) or EMD (clips) over the steps it ran."""
    from fbcpr.inference.prompt import goal_observation
    from fbcpr.metrics import d_smpl, emd

    table = Table(title="timeline")
    for col in ("segment", "kind", "seconds", "metric", "value"):
        table.add_column(col, justify="right" if col in ("seconds", "value") else "left")
    start = 0
    for seg in timeline.segments:
        stop = min(start + seg.steps, ep.steps)
        states = np.stack(ep.obs[start + 1: stop + 1]) if stop > start else None
        metric, value = "-", "not reached"
        if states is not None and seg.kind == "reward":
            metric, value = "mean reward", f"{ep.rewards(seg.label)[start:stop].mean():.3f}"
        elif states is not None and seg.kind == "goal":
            metric, value = "final d_smpl", f"{d_smpl(states[-1], goal_observation(seg.label, states.shape[1])[0]):.3f}"
        elif states is not None and seg.kind == "clip":
            metric, value = "EMD to clip", f"{emd(states, _load_clip(seg.label).obs):.3f}"
        table.add_row(seg.label, seg.kind, f"{seg.seconds:g}", metric, value)
        start += seg.steps
    return table


def register(app: typer.Typer) -> None:
    app.command("prompt")(prompt_command)
    app.command("track")(track_command)
    app.command("timeline")(timeline_command)
