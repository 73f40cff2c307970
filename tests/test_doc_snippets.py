"""Every ```python snippet of the README and docs/ runs: the blocks of one file in order, in one namespace, in a
folder that holds what they name (runs/demo and runs/small: a tiny untrained checkpoint; data/clips: clips).
A block preceded by `<!-- snippet: not run (reason) -->` is skipped (network, credentials)."""
import re
from pathlib import Path

import pytest

from doc_commands import tiny_bfm_parts

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"(<!-- snippet: not run[^>]*-->\s*)?```python\n(.*?)```", re.S)


def snippets(path):
    return [code for skip, code in BLOCK.findall(path.read_text()) if not skip]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """runs/demo, runs/small (a tiny humanoid checkpoint whose reward buffer holds clip and goal-pose states, so
    the documented reward prompts have states they reward) and data/clips (the synthetic clips)."""
    from fbcpr.core.checkpoint import save_checkpoint
    from motions.clip import save_clip
    from motions.synthetic import default_clips

    root = tmp_path_factory.mktemp("docs")
    model, cfg, buf = tiny_bfm_parts()
    clips = default_clips()
    for name in ("demo", "small"):
        save_checkpoint(root / "runs" / name, model, cfg, reward_buffer=buf)
    (root / "data" / "clips").mkdir(parents=True)
    for clip in clips:
        save_clip(clip, root / "data" / "clips" / f"{clip.name}.npz")
    return root


@pytest.mark.parametrize("doc", [p for p in DOCS if snippets(p)], ids=lambda p: p.name)
def test_doc_snippets_run(doc, workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    namespace = {"__name__": f"snippets_{doc.stem}"}
    for i, code in enumerate(snippets(doc)):
        try:
            exec(compile(code, f"{doc.name} snippet {i + 1}", "exec"), namespace)
        except Exception as err:
            raise AssertionError(f"{doc.name} snippet {i + 1} fails: {type(err).__name__}: {err}") from err
