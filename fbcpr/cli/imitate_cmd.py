"""`fbcpr imitate DEMO --reward NAME --out DIR`: single-demonstration imitation with TD3 and a learned imitation reward.

The one front door for the imitation rewards of `fbcpr.core.registry.IMITATION_REWARDS` (AMP, VIRL, ...). DEMO is
- a clip .npz: the humanoid imitates it (base config `<reward>-walk`, else `td3-cpu`, with env.motions = DEMO);
- a toy demonstration name (`circle-ccw`, ...): the 2-D point mass imitates it (base `<reward>-toy`, else `td3-toy`);
- a folder of frames: a video demonstration, for rewards with a `demo_frames` key (VIRL); the point mass is
  rendered and compared with it (base `<reward>-toy-video`), starting from uniform states (no demo states known).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from fbcpr.cli.common import cli_errors, console
from fbcpr.core.errors import InputError
from fbcpr.core.registry import IMITATION_REWARDS


class DemoError(ValueError):
    """A DEMO argument that is neither a clip, a folder of frames nor a toy demonstration."""


def _base_config(reward: str, kind: str, config: Path | None) -> Any:
    """The run config: --config, else the shipped `<reward>-<kind>` config, else the plain TD3 one of the env."""
    from fbcpr.core.config import find_config, load_config, shipped_configs

    if config is not None:
        return load_config(find_config(config))
    shipped = shipped_configs()
    fallback = {"walk": "td3-cpu", "toy": "td3-toy", "toy-video": "td3-toy"}[kind]
    return load_config(shipped.get(f"{reward}-{kind}", shipped[fallback]))


def imitation_config(demo: str, reward: str, config: Path | None = None) -> tuple[Any, str]:
    """(Config, env kind) for imitating `demo` with imitation reward `reward`; DemoError / ValueError when bad."""
    from fbcpr.envs.toy import demo_paths

    if reward not in IMITATION_REWARDS:
        raise ValueError(f"--reward: unknown imitation reward {reward!r}; choose from {sorted(IMITATION_REWARDS)}")
    path = Path(demo).expanduser()
    if path.is_dir():
        kind = "toy-video"
    elif path.is_file() and path.suffix == ".npz":
        kind = "walk"
    elif demo in demo_paths():
        kind = "toy"
    else:
        why = "does not exist" if not path.exists() else "is not a clip .npz or a folder of frames"
        raise DemoError(f"DEMO: {demo} {why}; give a clip .npz, a folder of frames, or a toy demonstration "
                        f"({', '.join(sorted(demo_paths()))})")
    cfg = _base_config(reward, kind, config)
    if cfg.algorithm != "td3":
        raise ValueError(f"--config: imitation trains TD3 (algorithm: td3), the config names {cfg.algorithm!r}")
    section = getattr(cfg.agent, reward)
    cfg.agent.reward.imitation, cfg.agent.reward.task = reward, None
    if kind == "toy-video":
        if not hasattr(section, "demo_frames"):
            raise DemoError(f"DEMO: {demo} is a folder of frames; --reward {reward} learns from states (give a clip "
                            "or a toy demonstration), a video needs a reward with video input")
        section.input, section.demo_frames = "video", str(path.resolve())
        cfg.env.name, cfg.env.motions, cfg.env.fall_prob = "toy", "synthetic", 1.0  # uniform starts only
    elif kind == "walk":
        cfg.env.name, cfg.env.motions = "humanoid", str(path.resolve())
    else:
        cfg.env.name, cfg.env.motions = "toy", demo
    return cfg, kind


@cli_errors
def imitate_command(
    demo: str = typer.Argument(..., help="A clip .npz (humanoid), a folder of frames (video, point mass) or a toy "
                               "demonstration name (circle-ccw, ...)."),
    reward: str = typer.Option(..., "--reward", metavar=f"<{'|'.join(sorted(IMITATION_REWARDS))}>",
                                help="Imitation reward."),
    out: Path = typer.Option(..., "--out", help="Run directory (checkpoints, metrics.csv)."),
    steps: int | None = typer.Option(None, "--steps", min=1, help="Total env steps, counted from 0 (overrides the "
                                        "config's); with --resume too."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its latest checkpoint "
                                "(same DEMO, --reward and --config)."),
    more_steps: int | None = typer.Option(None, "--more-steps", min=1, help="With --resume: train this many env "
                                             "steps beyond the latest checkpoint."),
    seed: int = typer.Option(0, "--seed", min=0, help="Training seed."),
    config: Path | None = typer.Option(None, "--config", help="A TD3 run config to start from instead of the "
                                          "shipped `<reward>-walk` / `<reward>-toy` one."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show the live progress bar."),
) -> None:
    """Imitate one demonstration: TD3 on the chosen learned imitation reward, trained online (Ctrl-C: final
    checkpoint; --resume continues it)."""
    import numpy as np

    from fbcpr.cli.run_folder import plan_run
    from fbcpr.core.paths import check_output_folder
    from fbcpr.train.trainer import Trainer

    inputs = [("DEMO", demo)] if Path(demo).expanduser().exists() else []
    check_output_folder(out, "--out", inputs + ([("--config", config)] if config is not None else []))
    cfg, kind = imitation_config(demo, reward, config)
    cfg.train.seed = seed
    if steps is not None and more_steps is not None:
        raise InputError("give --steps (the run's total) or --more-steps (beyond the checkpoint), not both")
    if steps is not None:
        cfg.train.total_env_steps = steps
        cfg.train.warmup_steps = min(cfg.train.warmup_steps, steps // 2)
    if not plan_run(cfg, out, resume, more_steps):
        return
    trainer = Trainer(cfg, out, resume=resume, progress=progress)
    try:
        summary = trainer.run()
    finally:
        trainer.close()
    console.print(f"{'interrupted' if summary['interrupted'] else 'finished'} at {summary['env_steps']:,} env steps, "
                  f"{summary['updates']:,} updates; checkpoint: {summary['checkpoint']}")
    if kind == "toy":  # seconds: score the policy against the demo next to a random one
        from fbcpr.eval.toy import imitation_metrics

        learned = imitation_metrics(trainer.agent.model.eval(), demo, np.random.default_rng(0))
        floor = imitation_metrics(None, demo, np.random.default_rng(0))
        console.print(f"DTW to {demo}: {learned['dtw']:.3f} (random {floor['dtw']:.3f}); demo shape reproduced: "
                      f"{learned['shape_coverage']:.0%} (random {floor['shape_coverage']:.0%})")


def register(app: typer.Typer) -> None:
    app.command("imitate")(imitate_command)
