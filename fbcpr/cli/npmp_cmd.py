"""`fbcpr npmp distill` (expert data from a BFM, then NPMP training with checkpoints and resume) and
`fbcpr npmp eval` (one-shot tracking relative to the expert)."""
from __future__ import annotations

import json
import time
from enum import Enum
from pathlib import Path

import typer
from rich.table import Table

from fbcpr.cli.common import HelpGroup, checkpoint_sources, cli_errors, console, progress
from fbcpr.core.errors import InputError

app = typer.Typer(help="Neural probabilistic motor primitives distilled from a BFM (NPMP).", no_args_is_help=True,
                  cls=HelpGroup)
DATA_FILE = "data.safetensors"
LOG_EVERY = 50  # gradient steps between lines of metrics.jsonl


class Method(str, Enum):
    bc = "bc"
    lfpc = "lfpc"


class Preset(str, Enum):
    paper = "paper"
    cpu = "cpu"
    tiny = "tiny"


@app.command("distill")
@cli_errors
def distill_command(
    expert: str = typer.Argument(..., help="The expert BFM: checkpoint dir, hub id or 'pretrained'."),
    motions: Path = typer.Option(..., "--motions", help="Folder of clip .npz files the expert tracks."),
    out: Path = typer.Option(..., "--out", help="Run directory: data.safetensors, checkpoints/, metrics.jsonl."),
    method: Method = typer.Option(Method.bc, "--method", help="bc: noisy rollouts; lfpc: one nominal rollout per "
                                  "clip with Jacobians (linear-feedback policy cloning)."),
    preset: Preset = typer.Option(Preset.cpu, "--preset", help="Model size: paper (encoder 2x1024, decoder 3x1024) "
                                  "or cpu (256 wide)."),
    steps: int = typer.Option(2000, "--steps", min=1, help="Total gradient steps of the run (with --resume too)."),
    latent: int | None = typer.Option(None, "--latent", help="Latent size (default 60)."),
    beta: float | None = typer.Option(None, "--beta", help="KL weight (default 0.1)."),
    alpha: float | None = typer.Option(None, "--alpha", help="AR(1) prior coefficient (default 0.95; 0: i.i.d.)."),
    rollouts: int = typer.Option(10, "--rollouts", min=1, help="BC: noisy rollouts per clip."),
    noise: float = typer.Option(0.1, "--noise", min=0.0, help="BC: std of the action noise (actions in [-1, 1])."),
    perturb: float = typer.Option(0.1, "--perturb", min=0.0, help="LFPC: perturbation std, as a fraction of each "
                                  "state dimension's std."),
    max_steps: int = typer.Option(300, "--max-steps", min=1, help="Longest expert episode, in env steps."),
    max_mb: float = typer.Option(1024.0, "--max-mb", min=1.0, help="Refuse a dataset larger than this."),
    checkpoint_every: int = typer.Option(500, "--checkpoint-every", min=1, help="Gradient steps between checkpoints."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the rollouts and of training."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out from its latest checkpoint."),
) -> None:
    """Collect expert data from a BFM tracking every clip, then distil it into an NPMP (Ctrl-C stops after the
    current gradient step with a checkpoint; --resume continues it)."""
    from fbcpr.apps.npmp.config import npmp_config
    from fbcpr.apps.npmp.data import ExpertData
    from fbcpr.apps.npmp.distill import distill
    from fbcpr.core.paths import check_output_folder

    check_output_folder(out, "--out", [*checkpoint_sources("the expert", expert), ("--motions", motions)])
    overrides = {k: v for k, v in (("latent_dim", latent), ("beta", beta), ("alpha", alpha)) if v is not None}
    cfg = npmp_config({**overrides, "seed": seed}, preset=preset.value)
    if resume and not (out / "checkpoints" / "latest").exists():
        raise InputError(f"--resume: no NPMP checkpoint to resume in {out}")
    data_path = out / DATA_FILE
    if data_path.exists():
        data = ExpertData.load(data_path)
        if data.method != method.value:
            raise InputError(f"{data_path} holds {data.method} data, not {method.value}: choose another --out")
        console.print(f"expert data: {data_path} ({len(data.obs):,} states, {len(data.episode_clip)} episodes)")
        collect_s = None
    else:
        data, collect_s = _collect(expert, motions, method.value, rollouts, noise, perturb, max_steps, max_mb, seed)
        data.save(data_path)
        console.print(f"expert data: {len(data.obs):,} states in {len(data.episode_clip)} episodes "
                      f"({collect_s:.0f} s) -> {data_path}")
    info = {"method": method.value, "expert": expert, "action_mapping": data.meta.get("action_mapping", "rest"),
            "clips": data.clip_names, "data": {k: v for k, v in data.meta.items() if k != "clips"}}
    start = time.time()
    with progress() as bar:
        task = bar.add_task(f"npmp {method.value}", total=steps)

        def report(step: int, metrics: dict[str, float]) -> None:
            bar.update(task, completed=step, description=f"npmp {method.value} loss {metrics['loss']:.2f} "
                                                         f"kl {metrics['kl']:.2f} mse {metrics['mse']:.4f}")
            if step == 1 or step % LOG_EVERY == 0:
                with open(out / "metrics.jsonl", "a") as log:
                    log.write(json.dumps({"step": step, "wall_s": round(time.time() - start, 1), **metrics}) + "\n")

        path, done = distill(out, data, cfg, steps, info, resume=resume, checkpoint_every=checkpoint_every,
                             on_update=report)
    state = "stopped by a signal at" if done < steps else "finished:"
    console.print(f"{state} {done:,} gradient steps ({time.time() - start:.0f} s in this command); checkpoint: {path}")


def _collect(expert: str, motions: Path, method: str, rollouts: int, noise: float, perturb: float, max_steps: int,
             max_mb: float, seed: int):
    from fbcpr.apps.npmp.data import collect
    from fbcpr.inference.bfm import BFM
    from motions.library import MotionLibrary

    bfm = BFM.load(expert)
    library = MotionLibrary.load(motions)
    start = time.time()
    with progress() as bar:
        task = bar.add_task(f"expert rollouts ({method})", total=None)
        data = collect(bfm, library, method, rollouts=rollouts, noise=noise, max_steps=max_steps,
                       perturb_scale=perturb, seed=seed, max_bytes=int(max_mb * 2**20),
                       on_step=lambda t, total: bar.update(task, completed=t, total=total))
    return data, time.time() - start


@app.command("eval")
@cli_errors
def eval_command(
    ckpts: list[str] = typer.Argument(..., help="NPMP run directories or checkpoints (the expert tracks once)."),
    motions: Path = typer.Option(..., "--motions", help="Folder of clip .npz files to track."),
    expert: str | None = typer.Option(None, "--expert", help="The expert to compare with (default: the BFM the "
                                         "NPMPs were distilled from)."),
    out: Path | None = typer.Option(None, "--out", help="Write results.json here."),
) -> None:
    """One-shot tracking of every clip by each NPMP and by the expert: EMD, success, and each NPMP relative to the
    expert (EMD_expert / EMD_npmp), on the clips it was distilled on and on held-out ones."""
    from fbcpr.apps.npmp.agent import NPMPAgent
    from fbcpr.apps.npmp.evaluate import relative_to_expert
    from fbcpr.eval.runner import tracking_suite, write_json
    from fbcpr.inference.agents import load_tracker
    from fbcpr.inference.bfm import BFM
    from motions.library import MotionLibrary

    loaded = [load_tracker(c) for c in ckpts]
    agents: list[NPMPAgent] = []
    for c, agent in zip(ckpts, loaded):
        if not isinstance(agent, NPMPAgent):
            raise InputError(f"{c}: not an NPMP checkpoint (`fbcpr eval` scores a BFM)")
        agents.append(agent)
    recorded = {str(a.info.get("expert", "pretrained")) for a in agents}
    if expert is None and len(recorded) > 1:
        raise InputError(f"the NPMPs were distilled from different experts {sorted(recorded)}: choose one with "
                         "--expert")
    expert = expert or recorded.pop()
    library = MotionLibrary.load(motions)
    with progress() as bar:
        teacher = tracking_suite(BFM.load(expert), library.clips, bar)
        results = {c: relative_to_expert(tracking_suite(a, library.clips, bar), teacher, a.info.get("clips", []))
                   for c, a in zip(ckpts, agents)}
    for c, agent in zip(ckpts, agents):
        results[c].update({"method": agent.info.get("method"), "steps": agent.info.get("steps")})
        console.print(_table(f"{c} ({agent.info.get('method')}) vs expert {expert}: one-shot tracking", results[c]))
    if out is not None:
        console.print(f"results written to [bold]{write_json({'expert': expert, 'npmp': results}, out)}[/]")


def _table(title: str, result: dict) -> Table:
    table = Table(title=title)
    for col in ("clip", "split", "EMD expert", "EMD npmp", "relative", "success expert", "success npmp"):
        table.add_column(col, justify="left" if col in ("clip", "split") else "right")
    for name, c in result["clips"].items():
        table.add_row(name, c["split"], f"{c['emd_expert']:.3f}", f"{c['emd']:.3f}", f"{c['relative_emd']:.2f}",
                      f"{c['success_expert']:.0f}", f"{c['success']:.0f}")
    for split, s in result["summary"].items():
        table.add_row(f"[bold]mean ({s['clips']})", split, f"{s['emd_expert']:.3f}", f"{s['emd']:.3f}",
                      f"{s['relative_emd_median']:.2f} (median)", f"{s['success_expert']:.2f}", f"{s['success']:.2f}")
    return table


def register(root: typer.Typer) -> None:
    root.add_typer(app, name="npmp")
