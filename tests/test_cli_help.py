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


def _all_commands():
    import typer.main

    group = typer.main.get_command(app)
    for name, cmd in group.commands.items():
        subs = getattr(cmd, "commands", None)
        yield from ([[name, sub] for sub in subs] if subs else [[name]])


def test_usage_lines_name_arguments_in_capitals_and_list_options_by_their_item():
    for args in _all_commands():
        text = run(*args, "--help").output
        usage = next(line for line in text.splitlines() if "Usage:" in line)
        assert "{" not in usage and usage == usage.replace(usage.split("[OPTIONS]")[-1],
                                                           usage.split("[OPTIONS]")[-1].upper()), (args, usage)
        assert "<list[" not in text and "<bool>" not in text, args
    assert "[OPTIONS] [CKPT] CLIP" in run("track", "--help").output
    assert "[OPTIONS] [CKPT] SPEC" in run("timeline", "--help").output
    assert "[OPTIONS] [CKPT]\n" in "\n".join(line.rstrip() for line in run("prompt", "--help").output.splitlines())
    assert "SOURCES..." in run("motions", "import", "--help").output


def test_fixed_choices_and_defaults_are_shown():
    def wide(*args):  # wide enough that no table cell wraps
        return CliRunner().invoke(app, [*args, "--help"], env={"COLUMNS": "250"}).output

    flat = {cmd: wide(cmd) for cmd in ("prompt", "imitate", "train", "export")}
    assert "<weighted|regression|backward|states|mix>" in flat["prompt"]
    assert "<cpu|cuda[:i]>" in flat["prompt"] and "<cpu|cuda[:i]|auto>" in flat["train"]
    assert "<amp|near|progress|virl>" in flat["imitate"]
    assert "[default: 0.5]" in flat["export"]
    for cmd in ("prompt", "track", "timeline", "eval"):
        assert "'pretrained' (the default)" in " ".join(run(cmd, "--help").output.split()), cmd
    narrow = CliRunner().invoke(app, ["demo", "--help"], env={"COLUMNS": "80"}).output
    assert "…" not in narrow and "[default: (quickstart)]" in " ".join(narrow.split())


def test_a_bad_choice_is_refused_before_any_work():
    res = run("prompt", "--reward", "jump-2", "--method", "best")
    assert res.exit_code == 2 and "best" in res.output
