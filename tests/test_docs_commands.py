"""Every shell command of docs/*.md and lab/README.md runs, the way tests/test_readme_commands.py runs the README's:
the commands of one file in order, in a fresh folder that holds what they read without making it themselves (tiny
untrained checkpoints at the run folders they name, the built-in synthetic clips under the clip names they use),
each with options that keep it short (tests/doc_commands.py SHORT, and SCRIPT_SHORT below for the repository's
scripts). bash expands each command (variables, loops, braces, globs); a loop runs its first value and a brace
list keeps its first item: one seed of a protocol that runs several. A command that is neither run nor in SKIP,
with its reason, fails the test, as does one that exits non-zero."""
from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import pytest
import torch

from doc_commands import (ROOT, SKIP, bash_commands, expand, one_pass, run_fbcpr, run_script, short_words,
                          tiny_bfm_parts, without_video)

DOCS = [p for p in [*sorted((ROOT / "docs").glob("*.md")), ROOT / "lab" / "README.md"] if bash_commands(p)]

#: Commands of docs/ and lab/README.md not run here, by how they start, and why (with SKIP's, shared with the README).
DOC_SKIP = {
    **SKIP,
    "HF_HUB_OFFLINE=1 fbcpr": "a Hugging Face Hub repo id: needs the network, or the repo in the local cache",
    "torchrun": "starts several processes (8 GPUs, several machines, or 2 ranks of the cpu config); "
                "tests/test_distributed.py runs `python -m fbcpr train` on 2 ranks over gloo",
    "python benchmarks/engine_speed.py --device cuda": "needs a CUDA GPU; the same script runs on the CPU here and in "
                                                       "tests/test_gpu_window.py's dry run of the GPU window",
    "fbcpr train runs/td3-npmp.yaml": "the config the user writes from the YAML block above it (a shipped TD3 config "
                                      "with env.npmp); TD3 in an NPMP's latent space is tested in "
                                      "tests/test_npmp_reuse.py",
}
#: Scripts not run here wherever a command (a loop's included) runs them, and why.
SCRIPT_SKIP = {
    "lab/experiments/targets.py": "a whole target table: every reward task, goal pose and clip, and 8 episodes of "
                                  "every behaviour family, for the model and both floors (a minute or more even "
                                  "at one episode of 60 steps)",
    "lab/experiments/compare_targets.py": "reads the tables of targets.py (not run here); its reading and rules "
                                          "are tested in lab/tests/test_compare_targets.py",
    "lab/experiments/learner_compiled.py": "compiles the learner (half a minute to minutes on a cold inductor cache); "
                                           "its counter is tested in tests/test_kernel_count.py",
    "lab/experiments/funnel_rise.py": "stabilises every planned rise with LQR gains along it, minutes a rise even "
                                      "for the short rises planned above; tested in lab/tests/test_funnel_rise.py",
}
#: Short options of the repository's scripts, as SHORT's for fbcpr commands (an option a command has takes the value
#: given here; `?--x`: only where the command has --x).
SCRIPT_SHORT = {
    "benchmarks/reward_relabel.py": ["--n", "2000", "--repeats", "1"],
    "benchmarks/env_throughput.py": ["--steps", "5", "--envs", "2", "--repeats", "1"],
    "benchmarks/prompt_speed.py": ["--n", "2000", "--preset", "tiny", "--act-calls", "5", "--repeats", "1"],
    "benchmarks/update_speed.py": ["--sizes", "tiny", "--reps", "1"],
    "benchmarks/bf16_agreement.py": ["--steps", "16", "--batches", "1"],
    "benchmarks/batch_draw.py": ["--sizes", "tiny", "--rows", "2000", "--updates", "2", "--reps", "1"],
    "benchmarks/engine_speed.py": ["--preset", "tiny", "--envs", "4", "--collectors", "1", "--warmup", "160",
                                   "--steps", "320", "--rollout", "40", "--no-compile"],
    "benchmarks/distributed_scaling.py": ["--ranks", "1", "--collect-steps", "512", "--train-steps", "512"],
    "lab/experiments/upright_time.py": ["--episodes", "1", "--steps", "5"],
    "lab/experiments/noise_copy.py": ["--reward-samples", "200"],
    "lab/experiments/rise_from_clip.py": ["--fractions", "0.5", "--episodes", "1"],
    "lab/experiments/clip_playback.py": ["--starts", "0", "--after", "2"],
    "lab/experiments/getup_planner.py": ["--seeds", "0", "--steps", "4", "--threads", "1", "?--fall-starts", "1",
                                         "--planner", "samples=4", "horizon=4"],
    "lab/experiments/skill_planner.py": ["--seeds", "0", "--steps", "40", "--threads", "1", "--planner", "samples=4",
                                         "horizon=4"],
    "lab/experiments/imitation_toy.py": ["--steps", "200"],
    "lab/experiments/imitation_humanoid.py": ["--env-steps", "64", "--seeds", "0", "--sheet-steps", "15"],
    "lab/experiments/npmp_latent_opt.py": ["--steps", "2"],
    "lab/experiments/npmp_toy.py": ["--steps", "5"],
    "lab/experiments/npmp_reuse_toy.py": ["--seeds", "0", "--steps", "64", "--eval-every", "32", "--distill-steps",
                                          "5"],
}
#: Words that stand for the reader's own choice, and what the test puts in their place.
PLACEHOLDERS = {"CKPT": "runs/demo", "R": "amp", "S": "0"}
#: Clip names the docs read from data/clips/deepmimic, mixed and cmu-heldout (and clip.npz, my_clips/, clips/): the
#: built-in synthetic clips stand in for them, by name.
CLIPS = {"walk": "walk", "run": "walk", "jump": "squat", "kick": "arm_raise", "crawl": "turn", "squat": "squat",
         "getup_facedown": "stand"}


#: Stock runs that one doc reads while another trains them itself (and must not find them there).
ONLY_FOR = {"runs/cpu": "benchmarks.md"}


def best_or_latest(word: str) -> str:
    """A run's `checkpoints/best` is written at its first evaluation, which a one-step run never reaches: there the
    latest checkpoint stands in for it."""
    path = Path(word)
    if path.name == "best" and path.parent.name == "checkpoints" and not path.exists():
        return str(path.parent / "latest")
    return word


def skipped(command: str) -> str | None:
    return next((why for prefix, why in DOC_SKIP.items() if command.startswith(prefix)), None)


@pytest.fixture(scope="module")
def stock(tmp_path_factory) -> Path:
    """What the documented commands read but do not make: clips, tiny untrained checkpoints where a reader would
    have trained one, a config and a frame folder of their own, and the source tree's lab/, benchmarks/ and
    fbcpr/configs/ (the docs run scripts from a source checkout)."""
    from fbcpr.core.checkpoint import save_checkpoint, write_pointer
    from fbcpr.core.config import load_config, shipped_configs
    from fbcpr.envs.toy import demo_paths
    from fbcpr.inference.bfm import pretrained_dir
    from fbcpr.rewards.virl.frames import rasterize_points, save_frames
    from fbcpr.train.trainer import Trainer
    from motions import synthetic
    from motions.clip import save_clip

    root = tmp_path_factory.mktemp("docs-commands")
    for name in ("lab", "benchmarks", "fbcpr"):
        (root / name).symlink_to(ROOT / name)
    for folder in ("data/clips/deepmimic", "data/clips/mixed", "data/clips/cmu-heldout", "my_clips", "clips"):
        (root / folder).mkdir(parents=True)
        for name, source in CLIPS.items():  # 1.5 s each: short to render, track and evaluate
            save_clip(dataclasses.replace(getattr(synthetic, source)(1.5), name=name), root / folder / f"{name}.npz")
    shutil.copy(root / "data/clips/deepmimic/walk.npz", root / "clip.npz")

    model, cfg, buf = tiny_bfm_parts()
    for path in ("runs/demo", "runs/quickstart/ckpt", "runs/mixed"):
        save_checkpoint(root / path, model, cfg, reward_buffer=buf)
    for run in ("runs/cpu", "runs/rollouts"):
        save_checkpoint(root / run / "checkpoints" / "step_0000000001", model, cfg, reward_buffer=buf)
        for pointer in ("latest", "best"):
            write_pointer(root / run / "checkpoints", pointer, "step_0000000001")
    for run in ("runs/mixed-rollouts-s1", "runs/mixed-rollouts-s2"):  # rollouts of a model of the shipped one's size
        (root / run / "checkpoints").mkdir(parents=True)
        (root / run / "checkpoints" / "step_0000000001").symlink_to(pretrained_dir())

    toy = load_config(shipped_configs()["toy"])
    toy.train.total_env_steps, toy.train.num_envs, toy.train.torch_threads = 64, 4, 1
    trainer = Trainer(toy, root / "toy-run", progress=False)
    step = Path(trainer.run()["checkpoint"])
    trainer.close()
    for run in ("runs/toy", "runs/toy-bench/seed0"):
        shutil.copytree(step, root / run / "checkpoints" / "step_0000060000")

    shutil.copy(shipped_configs()["quickstart"], root / "my.yaml")
    shutil.copy(shipped_configs()["cpu"], root / "my-continuation.yaml")
    save_frames(rasterize_points(torch.as_tensor(demo_paths()["circle-ccw"][:16]), 32).numpy(), root / "my_frames")
    return root


def test_every_doc_skip_is_still_documented():
    commands = [c for doc in DOCS for c in bash_commands(doc)]
    for prefix in DOC_SKIP.keys() - SKIP.keys():  # the shared ones: tests/test_readme_commands.py
        assert any(c.startswith(prefix) for c in commands), f"stale skip: {prefix}"
    for script in SCRIPT_SKIP:
        assert any(f"python {script}" in c for c in commands), f"stale skip: {script}"


#: Docs whose commands are not all run yet, and why (each a failure waiting to be fixed, not a pass).
NOT_YET: dict[str, str] = {}


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_documented_commands_run_in_order(doc, stock, tmp_path, monkeypatch):
    if doc.name in NOT_YET:
        pytest.skip(NOT_YET[doc.name])
    work = tmp_path / "work"
    shutil.copytree(stock, work, symlinks=True)
    for run, reader in ONLY_FOR.items():
        if doc.name != reader:
            shutil.rmtree(work / run)
    monkeypatch.chdir(work)
    monkeypatch.delenv("FBCPR_DATA", raising=False)  # the data directory is ./data, as on a fresh clone
    ran = 0
    for command in bash_commands(doc):
        if skipped(command):
            continue
        for key, value in PLACEHOLDERS.items():
            command = re.sub(rf"(?<![\w/.-]){key}(?![\w/.-])", value, command)
        for words in expand(one_pass(command), work):
            program, *rest = [best_or_latest(w) for w in words]
            if program == "fbcpr":
                code, output = run_fbcpr(short_words(without_video(rest)))
            else:
                assert program == "python", f"{doc.name}: a command that is neither run nor skipped: {command}"
                if rest[0] in SCRIPT_SKIP:
                    continue
                code, output = run_script(short_words(rest, SCRIPT_SHORT))
            assert code == 0, f"{doc.name}: `{' '.join(words)}` failed:\n{output[-3000:]}"
            ran += 1
    assert ran, f"{doc.name}: no command ran"
