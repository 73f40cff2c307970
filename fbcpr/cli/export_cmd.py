"""`fbcpr export CKPT OUT`: a compact inference checkpoint (model, config, a float16 reward subsample of states),
optionally with its weights interpolated towards the model it was trained on from (`--interpolate BASE`), and with
another model's reward states (`--reward-states-from MODEL`), with the named tasks' reward prompts inferred from
all of those states (`--store-prompts`), and some of those refined by rollouts (`--refine-prompts TASKS`, each
search from the zero-shot z or from a saved one, `--refine-from TASK=Z.npy`); or, with `--onnx`, the actor and B as
ONNX graphs with a JSON of sizes, action mapping and stored prompts (`fbcpr.inference.onnx_export`)."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import typer

from fbcpr.cli.common import checkpoint_sources, cli_errors, comma_names, console, given, progress


@cli_errors
def export_command(
    ctx: typer.Context,
    checkpoint: str = typer.Argument(..., help="Checkpoint dir, run dir, 'pretrained' or a Hugging Face repo id."),
    out: Path = typer.Argument(..., help="Folder to write the inference checkpoint into (replaced atomically); "
                                         "never CHECKPOINT itself, a folder inside or around it, or a file."),
    onnx: bool = typer.Option(False, "--onnx", help="Write the actor (obs, z -> action, the observation normaliser "
                              "inside) and B (obs -> embedding) as ONNX files with fbcpr-onnx.json (sizes, action "
                              "mapping, stored prompts' z's) instead of a checkpoint, for apps without torch; needs "
                              'pip install "fbcpr[onnx]".'),
    reward_samples: int = typer.Option(20_000, "--reward-samples", min=1,
                                       help="States kept for reward prompts (a seeded subsample of the buffer)."),
    half: bool = typer.Option(True, "--half/--full", help="Store the reward states as float16 (half the size)."),
    states_only: bool = typer.Option(True, "--states-only/--with-obs",
                                     help="Store the reward states without their observations, which loading "
                                          "rebuilds from qpos/qvel (a third of the size on the humanoid)."),
    interpolate_from: str = typer.Option(None, "--interpolate", metavar="BASE",
                                         help="Export (1 - alpha) * BASE + alpha * CHECKPOINT, weight by weight: "
                                              "BASE is the model CHECKPOINT's run continued from (WiSE-FT)."),
    alpha: float = typer.Option(0.5, "--alpha", min=0.0, max=1.0,
                                help="Weight of CHECKPOINT with --interpolate (0: BASE, 1: it)."),
    reward_states_from: list[str] = typer.Option(None, "--reward-states-from", metavar="MODEL",
                                                 help="Take the reward-prompt states from MODEL (e.g. 'pretrained') "
                                                      "instead of CHECKPOINT's own replay states; repeat it to pool "
                                                      "several models' states (then --reward-samples subsamples)."),
    store_prompts: bool = typer.Option(False, "--store-prompts/--no-store-prompts",
                                       help="Infer the reward prompts of the named tasks (fbcpr tasks) from every "
                                            "reward state before --reward-samples subsamples them, and store them "
                                            "for the prompts to use: z's that depend less on which states were "
                                            "kept (docs/usage.md)."),
    refine_prompts: str | None = typer.Option(None, "--refine-prompts", metavar="TASKS",
                                              help="Comma-separated named tasks whose stored prompts to refine by "
                                                   "rollouts for their own reward (as fbcpr prompt --refine does), "
                                                   "for tasks the regression prompts poorly; the zero-shot z is "
                                                   "kept beside each (docs/usage.md)."),
    refine: int = typer.Option(10, "--refine", min=1, help="With --refine-prompts: generations of the search."),
    refine_starts: int = typer.Option(8, "--refine-starts", min=1,
                                      help="With --refine-prompts: standing starts each candidate z is rolled out "
                                           "from."),
    refine_population: int = typer.Option(16, "--refine-population", min=2,
                                          help="With --refine-prompts: z's rolled out per generation."),
    refine_steps: int = typer.Option(300, "--refine-steps", min=1,
                                     help="With --refine-prompts: episode length in control steps (30 Hz)."),
    refine_seed: int = typer.Option(0, "--refine-seed",
                                    help="With --refine-prompts: seed of the search (its starts: seed + 1)."),
    refine_from: list[str] = typer.Option(None, "--refine-from", metavar="TASK=Z.npy",
                                          help="With --refine-prompts: start TASK's search from this saved z "
                                               "(fbcpr prompt --save-z, or any (z_dim,) .npy) instead of its "
                                               "zero-shot z; repeat it for several tasks."),
) -> None:
    """Write what inference needs and nothing else: no trainer state, no replay buffer."""
    from fbcpr.core.errors import InputError
    from fbcpr.core.extras import require
    from fbcpr.core.paths import check_output_folder
    from fbcpr.inference.bfm import BFM
    from fbcpr.inference.interpolation import interpolate, with_reward_states
    from fbcpr.inference.refine import Search, check_envs
    from fbcpr.inference.reward_prompts import infer_reward_prompts, refine_reward_prompts
    from humanoid_env.tasks.rewards import TASKS

    if onnx:
        stored_only = [f"--{n.replace('_', '-')}" for n in ("reward_samples", "half", "states_only") if given(ctx, n)]
        if stored_only:
            raise InputError(f"{', '.join(stored_only)}: set how a checkpoint stores its reward states, and --onnx "
                             "writes no checkpoint")
        require("onnxruntime", "onnx", "fbcpr export --onnx")
        require("onnxscript", "onnx", "fbcpr export --onnx")
    if given(ctx, "alpha") and interpolate_from is None:
        raise InputError("--alpha: only means something with --interpolate BASE")
    refining = comma_names(refine_prompts)
    loose = [f"--{n.replace('_', '-')}" for n in ("refine", "refine_starts", "refine_population", "refine_steps",
                                                  "refine_seed", "refine_from") if given(ctx, n)]
    if loose and not refining:
        raise InputError(f"{', '.join(loose)}: only mean something with --refine-prompts TASKS")
    unknown = [t for t in refining if t not in TASKS]
    if unknown:
        raise InputError(f"--refine-prompts: {', '.join(unknown)} not among the named tasks (fbcpr tasks lists them)")
    start_paths = start_z_paths(refine_from or [], refining)
    search = Search(generations=refine, population=refine_population, seed=refine_seed)
    check_envs(refine_population, refine_starts)
    sources = [*checkpoint_sources("the checkpoint to export", checkpoint),
               *checkpoint_sources("--interpolate", interpolate_from)]
    for src in reward_states_from or []:
        sources += checkpoint_sources("--reward-states-from", src)
    check_output_folder(out, "OUT", sources)  # before anything is read or written
    bfm = BFM.load(checkpoint)
    if interpolate_from is not None:
        bfm = interpolate(BFM.load(interpolate_from), bfm, alpha)
    if reward_states_from:
        bfm = with_reward_states(bfm, [BFM.load(src) for src in reward_states_from])
    starts_from = {t: read_z(p, bfm.z_dim, "--refine-from") for t, p in start_paths.items()}  # before any work
    if store_prompts:
        if bfm.env_name != "humanoid":
            raise InputError(f"--store-prompts: the named tasks are the humanoid's, and {checkpoint} was trained on "
                             f"{bfm.env_name!r}")
        replaced = sorted(set(bfm.reward_prompts.refined) - set(refining)) if bfm.reward_prompts is not None else []
        if replaced:  # a refined z came from rollouts, and a user may not know that the regression replaces it
            warnings.warn(f"--store-prompts replaces the refined prompts of {', '.join(replaced)} with zero-shot "
                          f"ones; to keep them refined, add --refine-prompts {','.join(replaced)}", stacklevel=1)
        with console.status(f"inferring {len(TASKS)} reward prompts from every reward state"):
            bfm.reward_prompts = infer_reward_prompts(bfm, TASKS)
        left_out = [t for t in TASKS if t not in bfm.reward_prompts.z]
        console.print(f"inferred {len(bfm.reward_prompts.z)} reward prompts from {bfm.reward_prompts.states:,} states"
                      + (f"; left out (they pay nothing on these states): {', '.join(left_out)}" if left_out else ""))
    if refining:
        with progress() as bar:
            task = bar.add_task(f"refining {len(refining)} prompts",
                                total=len(refining) * (refine * refine_population + 1) * refine_steps)
            bfm.reward_prompts = refine_reward_prompts(bfm, refining, search, refine_starts, refine_steps,
                                                       on_step=lambda k: bar.advance(task, k), start_from=starts_from)
        for name in refining:
            rec = bfm.reward_prompts.refined[name]
            console.print(f"refined {name}: mean reward on its starts {rec['score0']:.3f} -> {rec['score']:.3f}")
    if onnx:
        from fbcpr.inference.onnx_export import export_onnx

        with console.status("exporting the actor and B to ONNX"):
            path = export_onnx(bfm, out)
    else:
        held = len(bfm.reward_buffer["qpos"]) if bfm.reward_buffer is not None else 0
        if held > reward_samples:  # said, since re-exporting an exported model would drop its states unnoticed
            console.print(f"reward states: a seeded {reward_samples:,} of the {held:,} kept (--reward-samples)")
        path = bfm.save(out, reward_samples=reward_samples, half=half, states_only=states_only)
    sizes = {p.name: p.stat().st_size for p in sorted(path.iterdir())}
    for name, size in sizes.items():
        console.print(f"  {name:28s} {size / 2**20:8.2f} MiB")
    console.print(f"wrote [bold]{path}[/] ({sum(sizes.values()) / 2**20:.2f} MiB in all)")
    if interpolate_from is not None and not reward_states_from:
        console.print(f"its reward states are {checkpoint}'s; to try the mix's own (better for some mixes, worse for "
                      f"others: measure both): fbcpr train fbcpr/configs/own-states.yaml "
                      f"--init-from {path} --out RUN, then fbcpr export {path} OUT --reward-states-from RUN")


def start_z_paths(values: list[str], refining: list[str]) -> dict[str, Path]:
    """--refine-from TASK=PATH values by task, each naming a task of --refine-prompts once."""
    from fbcpr.core.errors import InputError

    out: dict[str, Path] = {}
    for value in values:
        task, sep, path = value.partition("=")
        if not sep or not task or not path:
            raise InputError(f"--refine-from: expected TASK=Z.npy, got {value!r}")
        if task not in refining:
            raise InputError(f"--refine-from: {task} is not among --refine-prompts ({', '.join(refining)})")
        if task in out:
            raise InputError(f"--refine-from: {task} is given twice")
        out[task] = Path(path)
    return out


def read_z(path: Path, z_dim: int, option: str) -> np.ndarray:
    """A saved z: one finite (z_dim,) float vector in a .npy file (no pickles, at most 1 MiB)."""
    from fbcpr.core.errors import InputError

    if not path.is_file():
        raise InputError(f"{option}: {path} is not a file")
    if path.stat().st_size > 2**20:
        raise InputError(f"{option}: {path} is {path.stat().st_size:,} bytes; a saved z is a few KB")
    try:
        z = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as err:
        raise InputError(f"{option}: {path} is not a .npy array ({err})") from err
    if z.shape != (z_dim,) or z.dtype.kind != "f" or not np.all(np.isfinite(z)):
        raise InputError(f"{option}: {path} must hold one finite float z of shape ({z_dim},), got {z.dtype} "
                         f"{z.shape}")
    return z.astype(np.float32)


def register(app: typer.Typer) -> None:
    app.command("export")(export_command)
