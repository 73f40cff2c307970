"""The README's shell commands run, in order, in a fresh folder, as `tests/test_doc_snippets.py` runs its Python:
each `fbcpr` command with extra options that keep it short (fewer steps and episodes; a later option wins over
the README's), and only the commands below in SKIP left out, each with its reason."""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fbcpr.cli.app import app

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCK = re.compile(r"```bash\n(.*?)```", re.S)

#: Commands not run here, by how they start, and why.
SKIP = {
    "pip install": "installs packages (network); the tests run in the installed environment",
    "python -m pytest": "the test suite itself",
    "fbcpr play": "serves its page until stopped (tests/test_play_browser.py runs it in a browser)",
    "fbcpr motions import path/to/": "the user's own motion files, which a fresh clone does not have (the import "
                                     "itself is tested in tests/test_motions_cli.py)",
}
#: Options appended to a command (by its first words) so that it runs in seconds.
SHORT = {
    "prompt": ["--steps", "5"],
    "eval": ["--episodes", "1", "--steps", "5"],
    # the behaviour checks read an episode's last second and half: two families of 2 s
    "eval --suite behaviours": ["--episodes", "1", "--steps", "60", "--tasks", "stand,get_up"],
    "train": ["--steps", "1", "--no-progress"],
    "export": ["--reward-samples", "200"],
    "export runs/cpu runs/cpu-onnx --onnx": [],  # no reward states in an ONNX export: nothing to shorten
    # the shipped NEAR config pretrains its energy network for 2,000 steps first (half a minute here): a tiny one
    "imitate": ["--steps", "1", "--no-progress", "--config", "tiny-near.yaml"],
    "npmp distill": ["--steps", "2", "--rollouts", "1", "--max-steps", "10", "--preset", "tiny"],
}
#: Commands whose `--video FILE` is left out here: rendering a 10 s rollout takes most of a minute on 2 cores
#: (videos are tested on a few frames in tests/test_cli_prompt.py; the README's prompt keeps its video here).
NO_VIDEO = ("track", "timeline")
TINY_NEAR = """algorithm: td3
model: {hidden_dim: 32, hidden_layers: 1}
agent:
  batch_size: 32
  reward: {imitation: near}
  near: {hidden_dim: 32, hidden_layers: 1, pretrain_steps: 5, dataset_size: 100}
env: {name: humanoid, max_episode_steps: 50, action_mapping: rest}
train: {num_envs: 4, warmup_steps: 100, rollout_steps: 40, updates_per_rollout: 1, buffer_capacity: 1000,
        priority_every: 0, eval_every: 0, checkpoint_every: 0, log_every: 100, reward_buffer_size: 0,
        torch_threads: 1}
"""


def readme_commands() -> list[str]:
    """Every command line of the README's bash blocks, in order, comments dropped."""
    lines = []
    for block in BLOCK.findall(README.read_text()):
        for line in block.splitlines():
            line = line.split(" #")[0].strip()
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


def without_video(words: list[str]) -> list[str]:
    if words[1] not in NO_VIDEO or "--video" not in words:
        return words
    i = words.index("--video")
    return words[:i] + words[i + 2:]


def short_options(words: list[str]) -> list[str]:
    for key in sorted(SHORT, key=len, reverse=True):
        if " ".join(words[1:]).startswith(key):
            return SHORT[key]
    return []


def test_the_readme_lists_commands_and_every_skip_is_still_there():
    commands = readme_commands()
    assert sum(c.startswith("fbcpr ") for c in commands) >= 10
    for prefix in SKIP:
        assert any(c.startswith(prefix) or f"&& {prefix}" in c for c in commands), f"stale skip: {prefix}"


def test_readme_commands_run_in_order(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("FBCPR_DATA", raising=False)  # the data directory is ./data, as on a fresh clone
    (tmp_path / "tiny-near.yaml").write_text(TINY_NEAR)
    runner = CliRunner()
    ran = []
    for command in readme_commands():
        if any(command.startswith(prefix) for prefix in SKIP):
            continue
        words = shlex.split(command)
        assert words[0] == "fbcpr", f"a README command that is neither run nor skipped: {command}"
        res = runner.invoke(app, without_video(words)[1:] + short_options(words))
        assert res.exit_code == 0, f"`{command}` failed:\n{res.output}"
        ran.append(words[1])
    assert {"prompt", "track", "timeline", "eval", "train", "export", "imitate", "npmp"} <= set(ran)
    assert (tmp_path / "data" / "clips" / "mixed" / "synthetic_walk.npz").is_file()
    assert (tmp_path / "runs" / "cpu-export" / "model.safetensors").is_file()
    assert (tmp_path / "runs" / "near" / "checkpoints").is_dir() and (tmp_path / "runs" / "npmp").is_dir()


@pytest.mark.parametrize("line, extra", [("fbcpr eval --quick", ["--episodes", "1", "--steps", "5"]),
                                         ("fbcpr npmp distill pretrained", SHORT["npmp distill"]),
                                         ("fbcpr tasks", [])])
def test_short_options_match_the_command(line, extra):
    assert short_options(shlex.split(line)) == extra
