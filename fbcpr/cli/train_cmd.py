"""`fbcpr train CONFIG.yaml`: online FB-CPR pre-training (fresh or resumed) into a run directory."""
from __future__ import annotations

from pathlib import Path

import typer

from fbcpr.cli.common import checkpoint_sources, cli_errors, console, err_console
from fbcpr.core.errors import InputError


@cli_errors
def train_command(
    config: str = typer.Argument(..., help="YAML run config, or the name of a shipped one (quickstart, small, cpu, "
                                 "paper-S, paper-M, toy). Relative paths inside it are read from its folder."),
    out: Path | None = typer.Option(None, "--out", help="Run directory (default: runs/<config name>)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its latest checkpoint."),
    steps: int | None = typer.Option(None, "--steps", min=1, help="Total env steps of the run, counted from 0 "
                                        "(overrides train.total_env_steps); with --resume too."),
    more_steps: int | None = typer.Option(None, "--more-steps", min=1, help="With --resume: train this many env "
                                             "steps of learning beyond the latest checkpoint (after the refill of "
                                             "an empty replay buffer, when the checkpoint holds none)."),
    device: str | None = typer.Option(None, "--device", metavar="<cpu|cuda[:i]|auto>",
                                       help="Override train.device."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the live progress bar (off: a plain "
                                  "log line every train.log_every env steps)."),
    init_from: str | None = typer.Option(None, "--init-from", help="Warm-start a new run from the weights of a "
                                            "checkpoint, inference-only ones included ('pretrained': the shipped "
                                            "model)."),
) -> None:
    """Train FB-CPR online; Ctrl-C (or SIGTERM, SIGHUP) stops at the next safe point with a final checkpoint.
    Data-parallel over processes and machines: `torchrun --nproc_per_node=N -m fbcpr train ...`."""
    from fbcpr.cli.run_folder import plan_run
    from fbcpr.core.config import find_config, load_config
    from fbcpr.core.errors import ConfigError
    from fbcpr.core.paths import check_output_folder
    from fbcpr.nn.distributed import launched_rank
    from fbcpr.train.trainer import resolve_device, train

    config_path = find_config(config)
    cfg = load_config(config_path)
    if steps is not None and more_steps is not None:
        raise typer.BadParameter("give --steps (the run's total) or --more-steps (beyond the checkpoint), not both")
    if steps is not None:
        cfg.train.total_env_steps = steps
    if device is not None:
        if not (device in ("cpu", "auto") or device.startswith("cuda")):
            raise ConfigError(f"--device: must be cpu, cuda[:i] or auto, got {device!r}")
        cfg.train.device = device
    resolve_device(cfg.train.device)  # fail before anything is written
    run_dir = out if out is not None else Path("runs") / config_path.stem
    if resume and init_from is not None:
        raise InputError("--init-from starts a new run; --resume continues one: give only one of them")
    check_output_folder(run_dir, "--out", checkpoint_sources("--init-from", init_from))
    if not plan_run(cfg, run_dir, resume, more_steps):
        return
    try:
        summary = train(cfg, run_dir, resume=resume, progress=progress, init_from=init_from)
    except KeyboardInterrupt:  # a second Ctrl-C: the checkpoints on disk are whole (written atomically)
        latest = run_dir / "checkpoints" / "latest"
        kept = f"the last checkpoint, {run_dir / 'checkpoints' / latest.read_text().strip()}, is intact" \
            if latest.is_file() else "no checkpoint had been written yet"
        err_console.print(f"[bold red]aborted[/]: {kept}", highlight=False)
        raise typer.Exit(130) from None
    state = "interrupted" if summary["interrupted"] else "finished"
    if launched_rank() == 0:
        console.print(f"{state} at {summary['env_steps']:,} env steps, {summary['updates']:,} updates; "
                      f"checkpoint: {summary['checkpoint']}")


def register(app: typer.Typer) -> None:
    app.command("train")(train_command)
