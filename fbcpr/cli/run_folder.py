"""A run folder's start or resume, shared by the commands that train (`fbcpr train`, `fbcpr imitate`): the checks
that keep a saved run from being overwritten, and the env-step total a resume continues to."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from fbcpr.cli.common import console
from fbcpr.core.errors import InputError


def plan_run(cfg: Any, run_dir: Path, resume: bool, more_steps: int | None) -> bool:
    """Check `run_dir` against `resume` and set cfg.train.total_env_steps (whole rollout phases; with
    `more_steps`, that many beyond the checkpoint). False when a resume has nothing left to do."""
    from fbcpr.nn.distributed import launched_rank
    from fbcpr.train.trainer import checkpoint_env_steps, resume_refill_steps

    if more_steps is not None and not resume:
        raise InputError("--more-steps continues a run: it needs --resume (a new run takes --steps)")
    latest = run_dir / "checkpoints" / "latest"
    if resume and not os.path.lexists(latest):  # a broken link is read later, which names what is wrong
        raise InputError(f"--resume: no checkpoint to resume in {run_dir}")
    if not resume and os.path.lexists(latest):
        raise InputError(f"--out: {run_dir} already holds a run; pass --resume to continue it or choose another --out")
    if not resume:
        _whole_phases(cfg, 0)
        return True
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
        return False
    return True


def _whole_phases(cfg: Any, done: int) -> None:
    """Round the run's total up to whole rollout phases (a run stops only between phases), and say so."""
    from fbcpr.nn.distributed import launched_rank
    from fbcpr.train.schedule import phase_steps

    tc = cfg.train
    if tc.total_env_steps <= done:  # nothing to do, which the caller says
        return
    phase = phase_steps(tc, 1) * tc.num_envs  # env steps a phase collects, over all processes
    total = done + -(-(tc.total_env_steps - done) // phase) * phase
    if total != tc.total_env_steps and launched_rank() == 0:
        console.print(f"train: {tc.total_env_steps - done:,} env steps rounded up to {total - done:,}, whole rollout "
                      f"phases of {phase:,} (train.rollout_steps over train.num_envs); the run ends at {total:,}",
                      highlight=False)
    tc.total_env_steps = total
