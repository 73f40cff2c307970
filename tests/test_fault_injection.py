"""What a fault-injection round found: each bad input gets a message that says what is wrong and what to do, not a
raw OS error or a silently wrong result."""
from __future__ import annotations

import builtins
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fbcpr.cli.app import app
from fbcpr.core.checkpoint import CheckpointError, latest_checkpoint
from fbcpr.core.config import load_config, shipped_configs
from fbcpr.core.errors import PromptError


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


def test_a_timeline_segment_shorter_than_one_control_step_is_refused_by_name():
    from fbcpr.inference.timeline import Timeline

    # checked before any prompt runs (prompt=None would fail at the first one)
    with pytest.raises(PromptError, match=r"segment 2 \(jump-2\): 1e-09 s is shorter than one control step"):
        Timeline.build(prompt=None, items=[("walk", 2.0), ("jump-2", 1e-9)])


@pytest.fixture
def unreadable_clip(tmp_path, monkeypatch) -> Path:
    """A clip file that the process may not read. As root, where chmod 000 does not stop reads, the operating
    system's refusal is raised for that one path by `open` itself; any other path opens as usual."""
    from motions.clip import save_clip
    from motions.synthetic import default_clips

    path = tmp_path / "walk.npz"
    save_clip(default_clips()[0], path)
    path.chmod(0)
    if os.geteuid() == 0:
        real_open = builtins.open

        def refusing_open(file, *args, **kwargs):
            if isinstance(file, (str, os.PathLike)) and Path(file) == path:
                raise PermissionError(13, "Permission denied", str(file))
            return real_open(file, *args, **kwargs)

        monkeypatch.setattr(builtins, "open", refusing_open)
    return path


def test_an_unreadable_clip_is_reported_as_unreadable_with_the_reason(unreadable_clip):
    from fbcpr.inference.prompt import load_motion  # what `fbcpr track` and `fbcpr prompt --imitate` read with

    with pytest.raises(PromptError) as err:
        load_motion(unreadable_clip)
    assert str(err.value) == f"{unreadable_clip}: cannot be read (Permission denied)"


def test_save_z_into_a_missing_folder_names_the_option_and_the_folder(tmp_path):
    target = tmp_path / "missing" / "z.npy"
    res = run("prompt", "pretrained", "--goal", "t_pose", "--steps", 1, "--save-z", target)
    assert res.exit_code == 1
    assert "--save-z" in res.output and f"the folder {tmp_path / 'missing'} does not exist" in res.output
    assert "Errno" not in res.output


def test_latest_as_a_link_to_a_step_folder_says_what_latest_must_be(tmp_path):
    root = tmp_path / "checkpoints"
    (root / "step_0000001600").mkdir(parents=True)
    (root / "latest").symlink_to("step_0000001600")
    with pytest.raises(CheckpointError, match="must be a text file holding the name of a checkpoint folder"):
        latest_checkpoint(root)


def test_a_checkpoints_folder_that_is_a_link_loop_is_named(tmp_path):
    from fbcpr.inference.bfm import resolve_checkpoint

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "checkpoints").symlink_to("checkpoints")
    for read in (lambda: resolve_checkpoint(run_dir), lambda: latest_checkpoint(run_dir / "checkpoints")):
        with pytest.raises(CheckpointError, match=r"run/checkpoints: a symbolic link loop"):
            read()


@pytest.mark.parametrize("command", [
    ["imitate", "circle-ccw", "--reward", "amp", "--steps", 100, "--no-progress"],
    ["eval", "random", "--suite", "goal", "--tasks", "t_pose", "--episodes", 1, "--steps", 2],
    ["motions", "synthetic"],
], ids=lambda c: " ".join(map(str, c[:2])))
def test_out_onto_an_existing_file_goes_through_the_output_folder_check(tmp_path, command):
    existing = tmp_path / "notes.txt"
    existing.write_text("keep me")
    res = run(*command, "--out", existing)
    assert res.exit_code == 1
    assert f"--out: {existing} is an existing file, not a folder" in res.output and "Errno" not in res.output
    assert existing.read_text() == "keep me"


@pytest.mark.parametrize("name", sorted(shipped_configs()))
def test_every_shipped_config_checkpoints_inside_its_run(name):
    train = load_config(shipped_configs()[name]).train
    assert train.checkpoint_every <= train.total_env_steps


def test_quickstart_checkpoints_within_a_few_minutes_of_training():
    """`fbcpr demo --train` trains quickstart for 5 minutes by default: about 3,200 env steps on a 2-core CPU. A
    run stopped then must have a checkpoint to resume from."""
    train = load_config(shipped_configs()["quickstart"]).train
    assert 0 < train.checkpoint_every <= 3_200 // 2
