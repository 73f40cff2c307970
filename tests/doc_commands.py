"""Shared by the tests that run documented shell commands (tests/test_readme_commands.py for the README,
tests/test_docs_commands.py for docs/ and lab/README.md): reading the commands out of ```bash blocks, the options
that keep each command short, and running an `fbcpr` command or a repository script in this process."""
from __future__ import annotations

import contextlib
import io
import itertools
import re
import runpy
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from typer.testing import CliRunner

from fbcpr.cli.app import app

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"```bash\n(.*?)```", re.S)

#: Commands not run, by how they start, and why (the README's and the docs' alike).
SKIP = {
    "pip install": "installs packages (network); the tests run in the installed environment",
    "python -m pytest": "the test suite itself",
    "fbcpr play": "serves its page until stopped (tests/test_play_browser.py runs it in a browser)",
    "fbcpr motions import": "the user's own motion files, which a fresh clone does not have (the import itself is "
                            "tested in tests/test_motions_cli.py)",
}
#: Options appended to an `fbcpr` command (by its first words, the longest match wins) so that it runs in seconds;
#: an option the command already has takes the value given here instead.
SHORT = {
    "prompt": ["--steps", "5"],
    "prompt --refine": ["--steps", "5", "--refine", "1", "--refine-starts", "1", "--refine-population", "2"],
    "track": [],
    "track --refine": ["--refine", "4", "--refine-rounds", "1"],
    "eval": ["--episodes", "1", "--steps", "5"],
    # the behaviour checks read an episode's last second and half: two families of 2 s
    "eval --suite behaviours": ["--episodes", "1", "--steps", "60", "--tasks", "stand,get_up"],
    "eval --suite tracking": [],
    "train": ["--steps", "1", "--no-progress"],
    "export": ["--reward-samples", "200"],
    "export runs/cpu runs/cpu-onnx --onnx": [],  # no reward states in an ONNX export: nothing to shorten
    "export --refine-prompts": ["--reward-samples", "200", "--refine", "1", "--refine-starts", "1",
                                "--refine-population", "2", "--refine-steps", "5"],
    "imitate": ["--steps", "1", "--no-progress"],
    "npmp distill": ["--steps", "2", "--rollouts", "1", "--max-steps", "10", "--preset", "tiny"],
    "motions render": ["--width", "64", "--height", "48"],
    "demo": ["--episodes", "1", "--eval-steps", "5", "--no-video"],
    "demo --train": ["--steps", "1", "--episodes", "1", "--eval-steps", "5", "--no-video"],
}
#: Options that a SHORT option replaces rather than joins (`--steps` instead of a time budget or `--more-steps`).
REPLACES = {"--steps": ("--minutes", "--more-steps")}
#: Commands whose `--video FILE` is left out: rendering a 10 s rollout takes most of a minute on 2 cores
#: (videos are tested on a few frames in tests/test_cli_prompt.py).
NO_VIDEO = ("track", "timeline")


def bash_commands(path: Path) -> list[str]:
    """Every command of a markdown file's bash blocks, in order: comments dropped, lines continued with a backslash
    joined, and a `for ... done` loop kept as one command (its lines joined by newlines)."""
    out: list[str] = []
    for block in BLOCK.findall(path.read_text()):
        pending, sep = "", " "
        for raw in block.splitlines():
            line = raw.split(" #")[0].strip()
            if line.startswith("#") or not line:
                continue
            pending = f"{pending}{sep}{line.removesuffix(chr(92)).strip()}".strip()
            if line.endswith("\\"):
                sep = " "
                continue
            if len(_DO.findall(pending)) > len(_DONE.findall(pending)):
                sep = "\n"
                continue
            out.append(pending)
            pending, sep = "", " "
    return out


_DO = re.compile(r"(?:^|(?<=[;\s]))do(?=\s|$)")
_DONE = re.compile(r"(?:^|(?<=[;\s]))done(?=[;\s]|$)")
#: bash functions that print the words a command would run with, one record per call (unit and record separators)
_RECORD = "".join(f'{name}() {{ printf "%s\\037" {name} "$@"; printf "\\036"; }}; '
                  for name in ("fbcpr", "python", "torchrun"))


def one_pass(command: str) -> str:
    """The command with every `for` loop over its first value only and every brace list `{a,b}` / `{0..5}` at its
    first item: one seed of a protocol that runs several."""
    command = re.sub(r"\bfor (\w+) in (\S+)[^;\n]*;\s*do\b", r"for \1 in \2; do", command)
    command = re.sub(r"\{([^{},]*),[^{}]*\}", r"\1", command)
    return re.sub(r"\{(-?\w+)\.\.[^{}]*\}", r"\1", command)


def expand(command: str, cwd: Path) -> list[list[str]]:
    """The word lists that bash runs for `command` in `cwd` (variables, loops, braces and globs expanded by bash
    itself), each starting with the program: fbcpr, python or torchrun."""
    import subprocess

    res = subprocess.run(["bash", "-c", _RECORD + command], cwd=cwd, capture_output=True, text=True, check=True)
    return [rec.split("\037")[:-1] for rec in res.stdout.split("\036")[:-1]]


def short_words(words: list[str], short: dict[str, list[str]] | None = None) -> list[str]:
    """`words` (a command without its program: `train cpu ...`, or `lab/experiments/x.py ...`) with the short
    options of its longest matching key in `short` (default SHORT; a key is the first word and any words the command
    must also hold): an option it already has takes the short value in place of its own, the others are appended."""
    table = SHORT if short is None else short
    keys = [k for k in table if words and k.split()[0] == words[0] and all(w in words for w in k.split()[1:])]
    out = list(words)
    if not keys:
        return out
    extra = table[max(keys, key=len)]
    for i, option in enumerate(extra):
        if not option.startswith(("--", "?--")):
            continue
        values = list(itertools.takewhile(lambda w: not w.startswith(("--", "?--")), extra[i + 1:]))
        if option.startswith("?"):  # only where the command has it
            option = option[1:]
            if option not in out:
                continue
        for other in REPLACES.get(option, ()):
            if other in out:
                j = out.index(other)
                del out[j:j + 1 + _n_values(out, j)]
        if option in out:
            j = out.index(option)
            out[j + 1:j + 1 + _n_values(out, j)] = values
        else:
            out += [option, *values]
    return out


def _n_values(words: list[str], i: int) -> int:
    """How many values follow the option at words[i] (up to the next option)."""
    return len(list(itertools.takewhile(lambda w: not w.startswith("--"), words[i + 1:])))


def without_video(words: list[str]) -> list[str]:
    """`words` without its `--video FILE` where the command is one of NO_VIDEO."""
    if words[0] not in NO_VIDEO or "--video" not in words:
        return words
    i = words.index("--video")
    return words[:i] + words[i + 2:]


def run_fbcpr(words: list[str]) -> tuple[int, str]:
    """(exit code, output) of an fbcpr command (without the program name), run in this process."""
    res = CliRunner().invoke(app, words, env={"COLUMNS": "200"})
    return res.exit_code, res.output + (f"\n{res.exception!r}" if res.exit_code and res.exception else "")


def run_script(words: list[str]) -> tuple[int, str]:
    """(exit code, output) of `python SCRIPT ARGS...`, run in this process (no interpreter start-up per command),
    with the script's folder first on sys.path as Python puts it (scripts import their siblings); the torch thread
    count the script sets and sys.path are put back after it."""
    threads, argv, path = torch.get_num_threads(), sys.argv, list(sys.path)
    buf = io.StringIO()
    code = 0
    try:
        sys.argv = [words[0], *words[1:]]
        sys.path.insert(0, str(Path(words[0]).resolve().parent))
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            runpy.run_path(words[0], run_name="__main__")
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        if stop.code not in (None, 0) and not isinstance(stop.code, int):
            buf.write(str(stop.code))
    except Exception as err:  # noqa: BLE001 - reported with the command that raised it
        code = 1
        buf.write(f"\n{type(err).__name__}: {err}")
    finally:
        sys.argv, sys.path[:] = argv, path
        torch.set_num_threads(threads)
    return code, buf.getvalue()


def split(command: str) -> list[str]:
    return shlex.split(command)


def tiny_bfm_parts() -> tuple[Any, Any, dict[str, np.ndarray]]:
    """(model, config, reward buffer) of an untrained tiny FB-CPR model whose reward buffer holds the built-in clips'
    and the goal poses' states, so that every documented reward prompt has states it rewards: the stand-in for a
    trained model in the docs' runs."""
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel
    from humanoid_env.tasks import GOALS, goal_obs, goal_qpos
    from motions.synthetic import default_clips

    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    clips = default_clips()
    buf = {"next_obs": np.concatenate([c.obs for c in clips] + [np.stack([goal_obs(g) for g in GOALS])]),
           "qpos": np.concatenate([c.qpos for c in clips] + [np.stack([goal_qpos(g) for g in GOALS])]),
           "qvel": np.concatenate([c.qvel for c in clips] + [np.zeros((len(GOALS), 75))])}
    return FBCPRModel(cfg.model), cfg, buf
