"""`fbcpr train CONFIG.yaml`: online FB-CPR pre-training (fresh or resumed) into a run directory."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

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
    from fbcpr.core.config import find_config, load_config
    from fbcpr.core.errors import ConfigError
    from fbcpr.core.paths import check_output_folder
    from fbcpr.nn.distributed import launched_rank
    from fbcpr.train.trainer import checkpoint_env_steps, resolve_device, resume_refill_steps, train

    config_path = find_config(config)
    cfg = load_config(config_path)
    if steps is not None and more_steps is not None:
        raise typer.BadParameter("give --steps (the run's total) or --more-steps (beyond the checkpoint), not both")
    if more_steps is not None and not resume:
        raise typer.BadParameter("--more-steps continues a run: it needs --resume (a new run takes --steps)")
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
    latest = run_dir / "checkpoints" / "latest"
    if resume and not os.path.lexists(latest):  # a broken link is read below, which names what is wrong
        raise InputError(f"--resume: no checkpoint to resume in {run_dir}")
    if not resume and os.path.lexists(latest):
        raise InputError(f"--out: {run_dir} already holds a run; pass --resume to continue it or choose another --out")
    if resume:
        done, refill = checkpoint_env_steps(run_dir), resume_refill_steps(run_dir, cfg)
        if more_steps is not None:  # N steps of learning: after the refill of an empty buffer, if there is one
            cfg.train.total_env_steps = done + refill + more_steps
        _whole_phases(cfg, done)
        if refill and done < cfg.train.total_env_steps and launched_rank() == 0:
            learn = cfg.train.total_env_steps - done - refill
            then = (f"then {learn:,} env steps of learning, to {cfg.train.total_env_steps:,} in all" if learn > 0
                    else f"the run's total, {cfg.train.total_env_steps:,}, comes before any update: --more-steps N "
                         "trains N steps beyond the refill")
            console.print(f"resume: {run_dir}'s checkpoint holds no replay buffer (train.save_buffer: false), so the "
                          f"loaded policy first refills an empty buffer for {refill:,} env steps, with no updates; "
                          f"{then}", highlight=False)
        if done >= cfg.train.total_env_steps:  # nothing to do: leave the run exactly as it is
            if launched_rank() == 0:
                console.print(f"nothing to do: {run_dir} is at {done:,} env steps, and the run's total is "
                              f"{cfg.train.total_env_steps:,} (--steps is the total; --more-steps N trains N more)")
            return
    if not resume:
        _whole_phases(cfg, 0)
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


def _whole_phases(cfg: Any, done: int) -> None:
    """Round the run's total up to whole rollout phases (a run stops only between phases), and say so."""
    from fbcpr.nn.distributed import launched_rank
    from fbcpr.train.schedule import phase_steps

    tc = cfg.train
    if tc.total_env_steps <= done:  # nothing to do, which the command says
        return
    phase = phase_steps(tc, 1) * tc.num_envs  # env steps a phase collects, over all processes
    total = done + -(-(tc.total_env_steps - done) // phase) * phase
    if total != tc.total_env_steps and launched_rank() == 0:
        console.print(f"train: {tc.total_env_steps - done:,} env steps rounded up to {total - done:,}, whole rollout "
                      f"phases of {phase:,} (train.rollout_steps over train.num_envs); the run ends at {total:,}",
                      highlight=False)
    tc.total_env_steps = total


def register(app: typer.Typer) -> None:
    app.command("train")(train_command)
