"""Shared CLI plumbing: one-line errors (traceback only with `--debug`), the global `--debug` flag, progress bars."""
from __future__ import annotations

import functools
import os
import re
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from typer.core import TyperGroup

from fbcpr.core.progress import LineProgress, progress_display

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
    """A command group whose help reads like other command-line tools: on/off flags bare (`--resume`, typer renders
    `--resume <bool>`), arguments in capitals in the usage line (`CKPT CLIP`, not `{ckpt} {clip_path}`) and
    repeatable options by their item type (`<str>`, not `<list[str]>`). `ctx` is click's Context, typed Any: the
    overridden methods take the base class, whose module depends on the typer version (newer ones vendor click)."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _tidy_params(super().get_params(ctx), ctx)

    def get_command(self, ctx: Any, name: str) -> Any:
        cmd = super().get_command(ctx, name)
        if cmd is not None and not isinstance(cmd, HelpGroup):
            _tidy_params(cmd.get_params(ctx), ctx)
        return cmd


def given(ctx: typer.Context, name: str) -> bool:
    """Whether the user passed option `name` (its Python name) rather than leaving its default, so options that do
    not apply to what was asked can be rejected instead of silently ignored."""
    source = ctx.get_parameter_source(name)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


def comma_names(values: str | list[str] | None) -> list[str]:
    """Names given comma-separated, in one option or a repeated one (`--tasks a,b --tasks c`), blanks dropped."""
    texts = [values] if isinstance(values, str) else values or []
    return [n.strip() for t in texts for n in t.split(",") if n.strip()]


def comma_ints(text: str | None, option: str) -> tuple[int, ...]:
    """Integers given comma-separated in one option (`--refine-leads 2,4,8`); a bad entry is an error naming
    the option."""
    try:
        return tuple(int(n) for n in comma_names(text))
    except ValueError:
        raise typer.BadParameter(f"{option}: expected comma-separated integers, got {text!r}") from None


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


#: The help of `--model` and of an optional CKPT argument: every command that runs a model defaults to the shipped one.
MODEL_HELP = ("Checkpoint directory, training run folder or Hugging Face repo id; 'pretrained' (the default) is the "
              "model that ships with the package.")


def choose_model(positional: str | None, model: str | None) -> str:
    """The checkpoint a command runs: the optional CKPT argument or `--model` (not two different ones), else the
    shipped pretrained model."""
    if positional is not None and model is not None and positional != model:
        raise typer.BadParameter(f"the model is named twice, {positional!r} and --model {model!r}: give one of them")
    return model or positional or "pretrained"


def model_and(args: list[str], what: str) -> tuple[str | None, str]:
    """Split `[CKPT] WHAT` positionals: one value is WHAT (the model is the default or --model), two are CKPT and
    WHAT, so both `fbcpr track clip.npz` and `fbcpr track pretrained clip.npz` read unambiguously."""
    if len(args) == 1:
        return None, args[0]
    if len(args) == 2:
        return args[0], args[1]
    raise typer.BadParameter(f"expected [CKPT] {what} (one or two values), got {len(args)}: {' '.join(args)}")


_LIST_TYPE = re.compile(r"^<list\[(\w+)\]>$")


def _tidy_params(params: list[Any], ctx: Any) -> list[Any]:
    for p in params:
        if getattr(p, "is_flag", False):
            p.metavar = ""
        elif getattr(p, "param_type_name", "") == "argument":
            name = p.metavar or p.name.upper()
            usage = name if p.required else f"[{name}]"
            usage += "..." if p.nargs != 1 and p.metavar is None else ""
            p.get_usage_pieces = lambda ctx=None, usage=usage: [usage]
            if p.nargs != 1:  # a variadic argument: its name says what it takes
                p.display_type_rich = lambda ctx=None: None
        elif p.metavar is None and hasattr(p, "display_type"):
            item = _LIST_TYPE.match(p.display_type(ctx))
            if item:
                p.metavar = f"<{item.group(1).lower()}>"
    return params


def register(app: typer.Typer) -> None:
    """Install the global `--debug` option as the app callback (the app has no other callback)."""
    app.callback(cls=HelpGroup)(_global_options)


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:
    """A warning as one yellow line, without the source line Python would print under it."""
    err_console.print(f"[bold yellow]warning:[/] {escape(str(message))}", highlight=False, soft_wrap=True)


def cli_errors(fn: F) -> F:
    """Turn any exception into a one-line red error and exit code 1, and a warning into one yellow line, unless
    debugging is on."""

    @functools.wraps(fn)
    def wrapper(*args: object, **kwargs: object) -> object:
        try:
            with warnings.catch_warnings():
                if not debug_enabled():
                    warnings.showwarning = _show_warning
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


def progress() -> Progress | LineProgress:
    """A rich progress bar with count, elapsed and remaining time on a terminal, plain progress lines in a log (on
    stderr either way, so stdout stays parseable)."""
    return progress_display(err_console, TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TimeRemainingColumn(), transient=True)
