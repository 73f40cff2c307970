"""`fbcpr --help` and friends: readable flags, a version, main commands first, a way to find the task names."""
import fbcpr
from typer.testing import CliRunner

from fbcpr.cli.app import app


def run(*args):
    return CliRunner().invoke(app, list(args), env={"COLUMNS": "100"})


def test_flags_are_shown_without_a_value_type():
    for args in ([], ["train"], ["prompt"], ["motions", "import"]):
        res = run(*args, "--help")
        assert res.exit_code == 0 and "--help" in res.output, args
        assert "<bool>" not in res.output, args
    assert "<int" in run("train", "--help").output  # options that take a value keep their type


def test_version():
    res = run("--version")
    assert res.exit_code == 0 and res.output.strip() == f"fbcpr {fbcpr.__version__}"


def test_main_commands_come_first_and_tasks_are_listed():
    text = run("--help").output
    positions = [text.index(f" {name} ") for name in ("train", "prompt", "track", "eval", "demo", "rollout")]
    assert positions == sorted(positions)
    assert "fbcpr tasks" in run("prompt", "--help").output
    res = run("tasks")
    assert res.exit_code == 0 and "jump-2" in res.output and "t_pose" in res.output and "Locomotion" in res.output
