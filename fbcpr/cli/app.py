"""Typer app behind the `fbcpr` console script. Each command group lives in its own module and registers itself here."""
from __future__ import annotations

import typer

from fbcpr.cli import (
    common,
    demo_cmd,
    env_cmd,
    eval_cmd,
    export_cmd,
    imitate_cmd,
    motions_cmd,
    npmp_cmd,
    play_cmd,
    prompt_cmd,
    tasks_cmd,
    train_cmd,
)

app = typer.Typer(help="FB-CPR behavioral foundation model for the SMPL humanoid.", no_args_is_help=True,
                  cls=common.HelpGroup)

# Command modules: each defines `register(app: typer.Typer) -> None`. Add one import + one call per module.
# `fbcpr --help` lists commands in this order: the main ones first.
common.register(app)
train_cmd.register(app)
imitate_cmd.register(app)
prompt_cmd.register(app)
eval_cmd.register(app)
demo_cmd.register(app)
play_cmd.register(app)
tasks_cmd.register(app)
motions_cmd.register(app)
export_cmd.register(app)
env_cmd.register(app)
npmp_cmd.register(app)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
