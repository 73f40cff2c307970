"""`fbcpr eval`: run the zero-shot benchmark (reward, goal, tracking suites) on a checkpoint or a floor baseline."""
from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from fbcpr.cli.common import (
    MODEL_HELP,
    checkpoint_sources,
    choose_model,
    cli_errors,
    comma_names,
    console,
    err_console,
    given,
)

if TYPE_CHECKING:
    import numpy as np

    from fbcpr.eval.behaviours import Refinement

#: `--quick`: a few tasks of each suite, the ones the shipped model does well and poorly, in under a minute.
QUICK_TASKS = ("move-ego-0-0", "move-ego-0-2", "crouch-0", "jump-2", "t_pose")
QUICK_CLIPS = 2
QUICK_EPISODES, QUICK_STEPS = 2, 150


class Suite(str, Enum):
    reward = "reward"
    goal = "goal"
    tracking = "tracking"
    all = "all"
    behaviours = "behaviours"


def _load_motions(folder: Path | None):
    if folder is not None:
        from motions.library import MotionLibrary

        return MotionLibrary.load(folder)
    from motions.synthetic import default_library

    return default_library()


@cli_errors
def eval_command(
    ctx: typer.Context,
    ckpt: str | None = typer.Argument(None, metavar="CKPT", show_default=False,
                                      help="The agent (as --model): a checkpoint (FB-CPR is prompted zero-shot; a "
                                           "single-task agent runs its own task, with imitation metrics when it "
                                           "imitates), or the floor baselines 'random' or 'zero'. " + MODEL_HELP),
    model: str | None = typer.Option(None, "--model", help=MODEL_HELP),
    suite: Suite = typer.Option(Suite.all, "--suite", help="Which suite to run: the paper's reward, goal and "
                                "tracking suites ('all' runs the three), or 'behaviours': physical checks of what "
                                "the body does (jump, get up, sit, ...) next to the zero and random floors."),
    tasks: list[str] | None = typer.Option(None, "--tasks", help="Restrict to these names (reward tasks such as "
                                              "move-ego-0-2, goal poses such as t_pose, clip names; with --suite "
                                              "behaviours, families such as jump); repeatable, or comma-separated."),
    episodes: int = typer.Option(10, "--episodes", min=1, help="Episodes per reward task and goal pose."),
    steps: int = typer.Option(300, "--steps", min=1, help="Steps per reward/goal episode (paper: 300)."),
    motions: Path | None = typer.Option(None, "--motions", help="Folder of clip .npz files: tracked clips and "
                                           "MoCap test states (default: the built-in synthetic clips)."),
    fall_prob: float = typer.Option(0.5, "--fall-prob", min=0.0, max=1.0, help="Share of Fall states in the test "
                                    "initial distribution."),
    out: Path = typer.Option(Path("eval_out"), "--out", help="Directory for results.json (rewritten after every "
                             "task, so Ctrl-C keeps what is done) and plots."),
    seed: int = typer.Option(0, "--seed", help="Seed of the initial states (and of the random baseline)."),
    quick: bool = typer.Option(False, "--quick", help=f"A check in under a minute on 2 CPU cores: "
                               f"{', '.join(QUICK_TASKS)} and the first {QUICK_CLIPS} clips, {QUICK_EPISODES} "
                               f"episodes of {QUICK_STEPS} steps (--episodes and --steps still apply)."),
    refine: int = typer.Option(0, "--refine", min=0, help="With --suite behaviours: first refine each family's "
                               "task prompt by this many generations of rollouts against the task's reward (as "
                               "`fbcpr prompt --refine`; 10 takes about 10 minutes a family on one CPU core)."),
) -> None:
    """Evaluate an agent zero-shot on reward tasks, goal poses and motion tracking (paper App. C.3)."""
    from fbcpr.core.paths import check_output_folder
    from fbcpr.eval.report import print_report
    from fbcpr.eval.runner import evaluate
    from fbcpr.inference.agents import make_agent

    check_output_folder(out, "--out", checkpoint_sources("CKPT", choose_model(ckpt, model))
                        + ([("--motions", motions)] if motions is not None else []))
    names = comma_names(tasks) or None
    if quick:
        if names is not None:
            raise typer.BadParameter("--quick runs its own short list of tasks (every family with --suite "
                                     "behaviours): give --quick or --tasks, not both")
        episodes = episodes if given(ctx, "episodes") else QUICK_EPISODES
        steps = steps if given(ctx, "steps") else QUICK_STEPS
    if suite == Suite.behaviours:
        _behaviours(ctx, choose_model(ckpt, model), names, episodes, steps, out, seed, refine)
        return
    if refine:
        raise typer.BadParameter("--refine applies to --suite behaviours (the benchmark's suites prompt zero-shot)")
    if suite == Suite.tracking:
        extra = [f"--{n.replace('_', '-')}" for n in ("episodes", "steps", "fall_prob") if given(ctx, n)]
        if extra:
            raise typer.BadParameter(f"{', '.join(extra)}: reward and goal episodes only; the tracking suite plays "
                                     "each clip once, from its first frame")
    ckpt = choose_model(ckpt, model)
    library = _load_motions(motions)
    if quick:
        names = [*QUICK_TASKS, *library.names[:QUICK_CLIPS]]
    agent = make_agent(ckpt, seed=seed)
    try:
        results = evaluate(agent, suite.value, tasks=names, episodes=episodes, motions=library, out=out, steps=steps,
                           fall_prob=fall_prob, seed=seed, agent_name=ckpt)
    except KeyboardInterrupt:
        done = out / "results.json"
        err_console.print("[bold red]interrupted[/]: " + (f"the tasks done so far are in {done}" if done.is_file()
                                                            else "no task had finished"), highlight=False)
        raise typer.Exit(130) from None
    print_report(results, console)
    console.print(f"results and plots written to [bold]{out}[/]")


def _behaviours(ctx: typer.Context, ckpt: str, names: list[str] | None, episodes: int, steps: int, out: Path,
                seed: int, refine: int) -> None:
    """`--suite behaviours`: the agent and the zero and random floors from the same standing, pushed and fall
    starts."""
    from fbcpr.eval.behaviours import FAMILIES, check, estimate_env_steps, families, refine_env_steps, table
    from fbcpr.inference.agents import make_agent

    extra = [f"--{n.replace('_', '-')}" for n in ("motions", "fall_prob") if given(ctx, n)]
    if extra:
        raise typer.BadParameter(f"{', '.join(extra)}: the behaviour checks start from standing, pushed and "
                                 "fall states of their own and track no clips")
    fams = families(names)
    agents = {name: make_agent(name, seed=seed) for name in dict.fromkeys((ckpt, "zero", "random"))}
    refinement = reward_refinement(refine, steps, seed) if refine else None
    total = sum(estimate_env_steps(fams, episodes, steps, a.z_dim > 0, refinement is not None)
                + refine_env_steps(fams, refinement) * (a.z_dim > 0) for a in agents.values())
    minutes = total * ENV_STEP_S / 60
    err_console.print(f"checking {len(fams)} of {len(FAMILIES)} behaviour families, each from its own start and "
                      f"one other, x {episodes} episodes x {steps} steps for {', '.join(agents)}: {total:,} env steps, "
                      f"about {max(1, round(minutes))} minute{'s' if minutes >= 1.5 else ''} on 2 CPU cores",
                      highlight=False)
    results = check(agents, names, episodes=episodes, steps=steps, seed=seed, out=out, refine=refinement)
    console.print(table(results))
    goals = results["families"].get("goal_poses", {})
    if "poses_reached" in goals:
        same = goals["reached_not_above_floors"]
        console.print(f"goal poses reached in half the episodes or more: {len(goals['poses_reached'])} of "
                      f"{len(goals['agents'][results['agent']][goals['start']]['poses'])}"
                      + (f"; no more often than by a floor on {len(same)} of them ({', '.join(same)})" if same else "")
                      + f"; mean success counting only poses reached more often than by both floors: "
                        f"{goals['success_above_floors']:.2f}", highlight=False)
    sheets = results.get("sheets")
    console.print(f"results in [bold]{out / 'behaviours.json'}[/]" + (f", contact sheets in [bold]{out / 'behaviours'}"
                                                                     "[/]" if isinstance(sheets, list) else
                                                                     f" ({sheets})"))


def reward_refinement(generations: int, steps: int, seed: int) -> Refinement:
    """`--refine`: a family's task prompt refined as `fbcpr prompt --refine` does, by the cross-entropy method over
    rollouts scored by the task's reward."""
    from fbcpr.eval.behaviours import REFINE_STARTS, Refinement
    from fbcpr.inference.refine import Search, refine, reward_objective

    def search(agent: Any, task: str, starts: tuple[np.ndarray, np.ndarray],
               on_step: Callable[[int], None] | None) -> np.ndarray:
        return refine(agent, agent.reward_z(task), reward_objective(task), starts, steps=steps,
                      search=Search(generations=generations, seed=seed), on_step=on_step).z

    population = Search(generations=generations).population
    return Refinement(search, generations, (generations * population + 1) * REFINE_STARTS * steps)


#: seconds per env step of the behaviour checks on 2 CPU cores (the model's prompts batched: 1.1 ms measured)
ENV_STEP_S = 0.0012


def register(app: typer.Typer) -> None:
    app.command("eval")(eval_command)
