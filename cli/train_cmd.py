"""`fbcpr train CONFIG.yaml`: online FB-CPR pre-training (fresh or resumed) into a run directory."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from fbcpr.cli.common import cli_errors, console


@cli_errors
def train_command(
    config: Path = typer.Argument(..., help="YAML run config (see configs/: quickstart, small, paper-S, paper-M, toy)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Run directory (default: runs/<config name>)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its latest checkpoint."),
    steps: Optional[int] = typer.Option(None, "--steps", min=1, help="Override train.total_env_steps."),
    device: Optional[str] = typer.Option(None, "--device", help="Override train.device (cpu, cuda, auto)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the live progress bar."),
    init_from: Optional[str] = typer.Option(None, "--init-from", help="Warm-start a new run from the weights of a "
                                            "checkpoint, inference-only ones included ('pretrained': the shipped model)."),
) -> None:
    """Train FB-CPR online; Ctrl-C (or SIGTERM) stops at the next safe point with a final checkpoint."""
    from fbcpr.config import ConfigError, load_config
    from fbcpr.trainer import train

    cfg = load_config(config)
    if steps is not None:
        cfg.train.total_env_steps = steps
    if device is not None:
        if not (device in ("cpu", "auto") or device.startswith("cuda")):
            raise ConfigError(f"--device: must be cpu, cuda[:i] or auto, got {device!r}")
        cfg.train.device = device
    run_dir = out if out is not None else Path("runs") / config.stem
    if resume and init_from is not None:
        raise ValueError("--init-from starts a new run; --resume continues one: give only one of them")
    if resume and not (run_dir / "checkpoints" / "latest").exists():
        raise FileNotFoundError(f"--resume: no checkpoint to resume in {run_dir}")
    if not resume and (run_dir / "checkpoints" / "latest").exists():
        raise FileExistsError(f"{run_dir} already holds a run; pass --resume to continue it or choose another --out")
    summary = train(cfg, run_dir, resume=resume, progress=progress, init_from=init_from)
    state = "interrupted" if summary["interrupted"] else "finished"
    console.print(f"{state} at {summary['env_steps']:,} env steps, {summary['updates']:,} updates; "
                  f"checkpoint: {summary['checkpoint']}")


def register(app: typer.Typer) -> None:
    app.command("train")(train_command)
