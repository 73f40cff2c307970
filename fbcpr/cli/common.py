"""Shared CLI plumbing: one-line errors (traceback only with `--debug`), the global `--debug` flag, progress bars."""
from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from typer.core import TyperGroup

F = TypeVar("F", bound=Callable[..., object])

console = Console()
err_console = Console(stderr=True)
_state = {"debug": False}


def _env_debug() -> bool:
    return os.environ.get("FBCPR_DEBUG", "") not in ("", "0")


def debug_enabled() -> bool:
    """True under `fbcpr --debug ...` or FBCPR_DEBUG=1."""
    return _state["debug"] or _env_debug()


def _print_version(value: bool) -> None:
    if value:
        import fbcpr

        console.print(f"fbcpr {fbcpr.__version__}", highlight=False)
        raise typer.Exit()


def _global_options(
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors (also FBCPR_DEBUG=1)."),
    version: bool = typer.Option(False, "--version", is_eager=True, callback=_print_version,
                                 help="Print the version and exit."),
) -> None:
    """FB-CPR behavioral foundation model for the SMPL humanoid."""
    _state["debug"] = debug  # set on every invocation, so one --debug run does not leak into the next


class HelpGroup(TyperGroup):
    """A command group whose help shows on/off flags bare (`--resume`), not as if they took a value
    (typer renders every flag's type, `--resume <bool>`). `ctx` is click's Context, typed Any: the overridden
    methods take the base class, whose module depends on the typer version (newer ones vendor click)."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _bare_flags(super().get_params(ctx))

    def get_command(self, ctx: Any, name: str) -> Any:
        cmd = super().get_command(ctx, name)
        if cmd is not None and not isinstance(cmd, HelpGroup):
            _bare_flags(cmd.get_params(ctx))
        return cmd


def given(ctx: typer.Context, name: str) -> bool:
    """Whether the user passed option `name` (its Python name) rather than leaving its default, so options that do
    not apply to what was asked can be rejected instead of silently ignored."""
    source = ctx.get_parameter_source(name)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


def checkpoint_sources(arg: str, value: str | Path | None) -> list[tuple[str, Path]]:
    """The local folders a checkpoint argument reads, as (argument, path) pairs for
    `fbcpr.core.paths.check_output_folder`: the path given (a run directory, a pointer file) and the checkpoint it
    resolves to; `pretrained` is the shipped model's folder. A Hugging Face repo id reads nothing local: none."""
    if value is None:
        return []
    from fbcpr.core.errors import FBCPRError
    from fbcpr.inference.bfm import PRETRAINED_DIR, PRETRAINED_NAME, resolve_checkpoint

    path = Path(value).expanduser()
    if not os.path.lexists(path):
        return [(arg, PRETRAINED_DIR)] if str(value) == PRETRAINED_NAME else []
    found = [(arg, path)]
    try:
        found.append((arg, resolve_checkpoint(path)))
    except FBCPRError:  # an unreadable source fails where it is read, with its own message
        pass
    return found


def _bare_flags(params: list[Any]) -> list[Any]:
    for p in params:
        if getattr(p, "is_flag", False):
            p.metavar = ""
    return params


def register(app: typer.Typer) -> None:
    """Install the global `--debug` option as the app callback (the app has no other callback)."""
    app.callback(cls=HelpGroup)(_global_options)


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
