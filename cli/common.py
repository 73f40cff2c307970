"""Shared CLI plumbing: one-line errors (traceback only with `--debug`), the global `--debug` flag, progress bars."""
from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

F = TypeVar("F", bound=Callable[..., object])

console = Console()
err_console = Console(stderr=True)
_state = {"debug": False}


def _env_debug() -> bool:
    return os.environ.get("FBCPR_DEBUG", "") not in ("", "0")


def debug_enabled() -> bool:
    """True under `fbcpr --debug ...` or FBCPR_DEBUG=1."""
    return _state["debug"] or _env_debug()


def _global_options(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors (also FBCPR_DEBUG=1)."),
) -> None:
    """FB-CPR behavioral foundation model for the SMPL humanoid."""
    _state["debug"] = debug  # set on every invocation, so one --debug run does not leak into the next


def register(app: typer.Typer) -> None:
    """Install the global `--debug` option as the app callback (the app has no other callback)."""
    app.callback()(_global_options)


def cli_errors(fn: F) -> F:
    """Turn any exception into a one-line red error and exit code 1, unless debugging is on."""

    @functools.wraps(fn)
    def wrapper(*args: object, **kwargs: object) -> object:
        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, KeyboardInterrupt):
            raise
        except Exception as err:
            if debug_enabled():
                raise
            msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            err_console.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
            err_console.print("[dim](run `fbcpr --debug ...` for the traceback)[/]")
            sys.stderr.flush()
            raise typer.Exit(1) from None

    return wrapper  # type: ignore[return-value]


def progress() -> Progress:
    """A rich progress bar with count, elapsed and remaining time (on stderr, so stdout stays parseable)."""
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err_console,
        transient=True,
    )
