"""The README's shell commands run, in order, in a fresh folder, as `tests/test_doc_snippets.py` runs its Python:
each `fbcpr` command with extra options that keep it short (fewer steps and episodes; a later option wins over
the README's), and only the commands in SKIP (tests/doc_commands.py) left out, each with its reason."""
from __future__ import annotations

import shlex

import pytest

from doc_commands import ROOT, SHORT, SKIP, bash_commands, run_fbcpr, short_words, without_video

README = ROOT / "README.md"
#: The README trains NEAR with `fbcpr imitate`: the shipped NEAR config pretrains its energy network for 2,000
#: steps first (half a minute here), so a tiny one stands in for it.
README_SHORT = {**SHORT, "imitate": ["--steps", "1", "--no-progress", "--config", "tiny-near.yaml"]}
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
    return bash_commands(README)


def test_the_readme_lists_commands_and_every_skip_is_still_there():
    commands = readme_commands()
    assert sum(c.startswith("fbcpr ") for c in commands) >= 10
    for prefix in SKIP:
        assert any(c.startswith(prefix) or f"&& {prefix}" in c for c in commands), f"stale skip: {prefix}"


def test_readme_commands_run_in_order(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("FBCPR_DATA", raising=False)  # the data directory is ./data, as on a fresh clone
    (tmp_path / "tiny-near.yaml").write_text(TINY_NEAR)
    ran = []
    for command in readme_commands():
        if any(command.startswith(prefix) for prefix in SKIP):
            continue
        words = shlex.split(command)
        assert words[0] == "fbcpr", f"a README command that is neither run nor skipped: {command}"
        code, output = run_fbcpr(short_words(without_video(words[1:]), README_SHORT))
        assert code == 0, f"`{command}` failed:\n{output}"
        ran.append(words[1])
    assert {"prompt", "track", "timeline", "eval", "train", "export", "imitate", "npmp"} <= set(ran)
    assert (tmp_path / "data" / "clips" / "mixed" / "synthetic_walk.npz").is_file()
    assert (tmp_path / "runs" / "cpu-export" / "model.safetensors").is_file()
    assert (tmp_path / "runs" / "near" / "checkpoints").is_dir() and (tmp_path / "runs" / "npmp").is_dir()


@pytest.mark.parametrize("line, short", [
    ("fbcpr eval --quick", "eval --quick --episodes 1 --steps 5"),
    ("fbcpr npmp distill pretrained", "npmp distill pretrained " + " ".join(SHORT["npmp distill"])),
    ("fbcpr tasks", "tasks"),
    ("fbcpr eval --suite behaviours --tasks jump --episodes 4",
     "eval --suite behaviours --tasks stand,get_up --episodes 1 --steps 60"),
    ("fbcpr train small --resume --more-steps 100000", "train small --resume --steps 1 --no-progress"),
])
def test_short_options_match_the_command(line, short):
    assert short_words(shlex.split(line)[1:]) == short.split()
