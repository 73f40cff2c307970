"""`fbcpr play`: the humanoid simulated and drawn live in a local web page, prompted from the page (reward tasks,
goal poses, clips, timelines) while it runs (`fbcpr.apps.play`; needs `pip install "fbcpr[play]"`)."""
from __future__ import annotations

from pathlib import Path

import typer

from fbcpr.cli.common import cli_errors, console

#: The prompt the body starts under: standing still (the T-pose goal for a model that has no reward states).
FIRST_PROMPT, FIRST_GOAL = "move-ego-0-0", "t_pose"


@cli_errors
def play_command(
    model: str = typer.Option("pretrained", "--model", help="Checkpoint dir, run dir, 'pretrained' (the shipped "
                              "model) or a Hugging Face repo id."),
    clip: list[Path] = typer.Option(None, "--clip", metavar="FILE",
                                    help="A clip .npz to offer on the page beside the data folder's; repeatable."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to serve on (0.0.0.0: every interface, so "
                             "other machines can open the page)."),
    port: int = typer.Option(8080, "--port", min=1, max=65535,
                             help="Port to serve on (the next free one if it is taken)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the starts, falls and pushes."),
) -> None:
    """Open the printed address in a browser: pick a reward task, a goal pose, a clip or a timeline, and the body
    takes the new prompt as it moves; reset, push, pause, step, slow it down, follow it with the camera."""
    from fbcpr.apps.play.page import Playground
    from fbcpr.apps.play.session import Prompts, Session, check_clip_files, clip_choices
    from fbcpr.core.config import data_dir
    from fbcpr.core.errors import InputError, PromptError
    from fbcpr.core.extras import require
    from fbcpr.inference.bfm import BFM
    from fbcpr.inference.prompt import builtin_clip_names
    from humanoid_env.tasks import TASKS, goal_names

    require("viser", "play", "fbcpr play")
    check_clip_files(clip or [])
    bfm = BFM.load(model)
    if bfm.env_name != "humanoid":
        raise InputError(f"--model: {model} was trained on {bfm.env_name!r}; the playground shows the humanoid")
    prompts = Prompts(bfm)
    try:
        first = prompts.reward(FIRST_PROMPT)
    except PromptError:  # a model without reward states still takes goal poses and clips
        first = prompts.goal(FIRST_GOAL)
    session = Session(bfm, first, seed=seed)
    clips = clip_choices(data_dir(), clip or [], builtin_clip_names())
    page = Playground(session, prompts, sorted(TASKS), goal_names(), clips, host=host, port=port)
    console.print(f"the body starts under the {first.kind} {first.label}")
    console.print(f"fbcpr play: open [bold]{page.url}[/] (Ctrl-C stops)", soft_wrap=True)
    try:
        page.run()
    except KeyboardInterrupt:
        pass
    finally:
        page.stop()


def register(app: typer.Typer) -> None:
    app.command("play")(play_command)
