"""`fbcpr rollout`: run the SMPL humanoid with a trivial policy, print throughput and pose stats, optionally a video."""
from __future__ import annotations

import time
from enum import Enum
from pathlib import Path

import typer
from rich.table import Table

from fbcpr.cli.common import cli_errors, console, progress


class Policy(str, Enum):
    zero = "zero"
    random = "random"


@cli_errors
def rollout_command(
    steps: int = typer.Option(300, "--steps", min=1, help="Control steps (30 Hz) to simulate."),
    policy: Policy = typer.Option(Policy.zero, "--policy", help="zero: every PD target at its range's middle; "
                                  "random: uniform actions in [-1, 1]."),
    video: Path | None = typer.Option(None, "--video", help="Write an mp4 of the rollout from the tracking camera."),
    seed: int = typer.Option(0, "--seed", help="Seed of the initial state and of the random policy."),
    fall_prob: float = typer.Option(0.0, "--fall-prob", min=0.0, max=1.0, help="Probability of starting from a "
                                    "random fall instead of the standing pose."),
) -> None:
    """Simulate the humanoid and report steps/s, pelvis height and divergences (episodes end at --steps)."""
    import numpy as np

    from humanoid_env.env import HumanoidEnv
    from humanoid_env.inits import make_init
    from humanoid_env.model import N_SUBSTEPS
    from humanoid_env.render import TrackRenderer, write_video

    env = HumanoidEnv(init=make_init(fall_prob), max_episode_steps=steps)
    renderer = TrackRenderer(env.model, 240, 320) if video is not None else None  # fails early, naming MUJOCO_GL
    rng = np.random.default_rng(seed)
    _, info = env.reset(seed=seed)
    frames = [renderer.render(env.data)] if renderer else []
    heights, diverged, step_seconds = [info["qpos"][2]], 0, 0.0
    wall = time.perf_counter()
    with progress() as bar:
        task = bar.add_task("rollout", total=steps)
        for _ in range(steps):
            action = rng.uniform(-1, 1, 69).astype(np.float32) if policy is Policy.random else np.zeros(69, np.float32)
            t = time.perf_counter()
            _, _, terminated, truncated, info = env.step(action)
            step_seconds += time.perf_counter() - t
            heights.append(info["qpos"][2])
            if info["diverged"]:
                diverged += 1
            if terminated or truncated:
                _, info = env.reset()
            if renderer:
                frames.append(renderer.render(env.data))
            bar.advance(task)
    wall = time.perf_counter() - wall
    h = np.asarray(heights)

    table = Table(title=f"humanoid rollout ({policy.value} policy, seed {seed})")
    for col in ("steps", "sim s", "wall s", "steps/s", "pelvis z min", "mean", "final", "diverged"):
        table.add_column(col, justify="right")
    sim_seconds = steps * env.model.opt.timestep * N_SUBSTEPS
    table.add_row(str(steps), f"{sim_seconds:.1f}", f"{wall:.2f}", f"{steps / step_seconds:.0f}", f"{h.min():.3f}",
                  f"{h.mean():.3f}", f"{h[-1]:.3f}", str(diverged))
    console.print(table)
    if renderer:
        assert video is not None  # the renderer exists for --video only
        renderer.close()
        console.print(f"video written to [bold]{write_video(frames, video, fps=30)}[/]")


def register(app: typer.Typer) -> None:
    app.command("rollout")(rollout_command)
