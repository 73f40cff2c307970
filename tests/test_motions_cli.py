"""`fbcpr motions import/info/render`: failures are reported per file and never destroy earlier outputs."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from fbcpr.cli.app import app
from motions.clip import load_clip

sys.path.insert(0, str(Path(__file__).parent))
from test_motions_bvh import _squat_bvh  # noqa: E402  (a CMU-style BVH writer)

runner = CliRunner()


def _malformed(folder: Path) -> dict[str, str]:
    """Six broken inputs of every format, each with a word its error message must contain."""
    folder.mkdir()
    text, _ = _squat_bvh(n=6)
    (folder / "squat.bvh").write_text(text.replace("Frames: 6", "Frames: 7"))  # same name as a good clip
    (folder / "cut.txt").write_text('{"Loop": "wrap", "Frames": [[0.03, 1')
    (folder / "notes.txt").write_text("just some notes")
    np.savez(folder / "amass_nan.npz", poses=np.full((4, 72), np.nan), trans=np.zeros((4, 3)), mocap_framerate=30.0)
    np.savez(folder / "amass_no_trans.npz", poses=np.zeros((4, 72)), mocap_framerate=30.0)
    (folder / "empty.bvh").write_text("")
    return {"squat.bvh": "values, found", "cut.txt": "not a readable DeepMimic JSON", "notes.txt": "not a supported motion file",
            "amass_nan.npz": "NaN or inf", "amass_no_trans.npz": "missing 'trans'", "empty.bvh": "not a supported motion file"}


def test_import_reports_failures_and_keeps_earlier_outputs(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    good = tmp_path / "good"
    good.mkdir()
    text, _ = _squat_bvh(n=20)
    (good / "squat.bvh").write_text(text)
    out = tmp_path / "clips"
    first = runner.invoke(app, ["motions", "import", str(good), "--out", str(out)])
    assert first.exit_code == 0, first.output
    saved = (out / "squat.npz").read_bytes()
    assert load_clip(out / "squat.npz").n_frames == 10

    expected = _malformed(tmp_path / "bad")
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "bad"), "--out", str(out)])
    assert res.exit_code == 1
    summary = json.loads((out / "import_summary.json").read_text())
    assert [c["clip"] for c in summary["clips"]] == ["squat.npz"]  # merged: the first import's clip stays listed
    reasons = {Path(f["file"]).name: f["reason"] for f in summary["failures"]}
    assert set(reasons) == set(expected)
    for name, word in expected.items():
        assert word in reasons[name] and name in reasons[name], (name, reasons[name])
    assert (out / "squat.npz").read_bytes() == saved  # the failed squat.bvh left the earlier clip untouched
    assert sorted(p.name for p in out.iterdir()) == ["import_summary.json", "squat.npz"]  # no temp files

    # a good and a bad file together: the good one is written, the run still says it failed
    (tmp_path / "mixed").mkdir()
    (tmp_path / "mixed" / "again.bvh").write_text(text)
    (tmp_path / "mixed" / "junk.txt").write_text("{ nope")
    (tmp_path / "mixed" / "README.md").write_text("# where these takes come from")  # no motion: skipped, not failed
    (tmp_path / "mixed" / "index.csv").write_text("take,description")
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "mixed"), "--out", str(out)])
    assert res.exit_code == 1 and (out / "again.npz").is_file()
    assert "skipped 2 files in the folders that hold no motion: README.md, index.csv" in " ".join(res.output.split())
    summary = json.loads((out / "import_summary.json").read_text())
    assert [c["clip"] for c in summary["clips"]] == ["squat.npz", "again.npz"] and len(summary["failures"]) == 7
    assert summary["total_seconds"] == round(sum(c["seconds"] for c in summary["clips"]), 3)


def test_import_names_the_clipped_joints(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    text, _ = _squat_bvh(n=20)
    (tmp_path / "squat.bvh").write_text(text)
    from motions.retarget import RetargetReport

    real = RetargetReport.__init__

    def with_clipping(self, *args, **kwargs):  # a source beyond the joint limits, as real mocap often is
        real(self, *args, **kwargs)
        self.clipped = {"L_Knee_y": 8, "R_Elbow_x": 4}

    monkeypatch.setattr(RetargetReport, "__init__", with_clipping)
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "squat.bvh"), "--out", str(tmp_path / "out"),
                              "--no-cache"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "12: L_Knee_y 8, R_Elbow_x 4" in res.output
    summary = json.loads((tmp_path / "out" / "import_summary.json").read_text())
    assert summary["clips"][0]["clipped_joints"] == {"L_Knee_y": 8, "R_Elbow_x": 4}


def test_info_lists_clips_and_flags_invalid_ones(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    text, _ = _squat_bvh(n=20)
    (tmp_path / "squat.bvh").write_text(text)
    out = tmp_path / "clips"
    assert runner.invoke(app, ["motions", "import", str(tmp_path / "squat.bvh"), "--out", str(out)]).exit_code == 0
    (out / "broken.npz").write_bytes(b"garbage")
    res = runner.invoke(app, ["motions", "info", str(out)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "squat" in res.output and "invalid" in res.output and "1 clip(s)" in res.output
    res = runner.invoke(app, ["motions", "info", str(tmp_path / "nowhere")])
    assert res.exit_code == 1 and "is not a folder" in res.output


def test_render_writes_frames_or_says_why_not(tmp_path, monkeypatch):
    from humanoid_env.render import renderer_available
    from motions.clip import save_clip
    from motions.synthetic import arm_raise

    clip = save_clip(arm_raise(seconds=1.0), tmp_path / "arm.npz")
    out = tmp_path / "arm.png"
    res = runner.invoke(app, ["motions", "render", str(clip), str(out), "--width", "64", "--height", "48", "--stills", "3"])
    if renderer_available():
        import imageio.v2 as imageio

        assert res.exit_code == 0, res.output
        img = imageio.imread(out)
        assert img.shape == (48, 192, 3) and img.std() > 5  # three frames side by side, not blank
    else:
        assert res.exit_code == 1 and "no OpenGL renderer available" in res.output
    res = runner.invoke(app, ["motions", "render", str(tmp_path / "missing.npz"), str(out)])
    assert res.exit_code == 1 and "no such clip file" in res.output


def test_import_with_a_joint_map(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    text, _ = _squat_bvh(n=20)
    (tmp_path / "odd.bvh").write_text(text.replace("JOINT LeftHand\n", "JOINT wrist_a\n"))
    out = tmp_path / "out"
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "odd.bvh"), "--out", str(out)], env={"COLUMNS": "300"})
    assert res.exit_code == 1 and "no joint for l_wrist" in res.output
    (tmp_path / "map.yaml").write_text("l_wrist: wrist_a\n")
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "odd.bvh"), "--out", str(out),
                              "--joint-map", str(tmp_path / "map.yaml")], env={"COLUMNS": "300"})
    assert res.exit_code == 0 and (out / "odd.npz").is_file(), res.output
    (tmp_path / "bad.yaml").write_text("l_wrist: [wrist_a\n")
    res = runner.invoke(app, ["motions", "import", str(tmp_path / "odd.bvh"), "--out", str(out),
                              "--joint-map", str(tmp_path / "bad.yaml")], env={"COLUMNS": "300"})
    assert res.exit_code == 1 and "bad.yaml:2:1: invalid YAML" in res.output


def test_synthetic_writes_the_built_in_clips_beside_others_without_a_clash(tmp_path):
    from motions.library import MotionLibrary
    from motions.synthetic import stand

    res = runner.invoke(app, ["motions", "synthetic", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    names = sorted(p.stem for p in tmp_path.glob("*.npz"))
    assert names == sorted(f"synthetic_{n}" for n in ("stand", "tpose", "arm_raise", "squat", "walk", "turn"))
    clip = load_clip(tmp_path / "synthetic_stand.npz")
    assert clip.name == "synthetic_stand"
    np.testing.assert_allclose(clip.qpos, stand().qpos)
    assert sorted(MotionLibrary.load(tmp_path).names) == names
    before = (tmp_path / "synthetic_walk.npz").read_bytes()
    again = runner.invoke(app, ["motions", "synthetic", "--out", str(tmp_path)])
    assert again.exit_code == 1 and "already exist" in again.output  # nothing is overwritten
    assert (tmp_path / "synthetic_walk.npz").read_bytes() == before
    bad = runner.invoke(app, ["motions", "synthetic", "--out", str(tmp_path), "--prefix", "../x"])
    assert bad.exit_code != 0 and "--prefix" in bad.output


def test_import_of_a_missing_file_prints_no_table_and_outputs_follow_the_umask(tmp_path, monkeypatch):
    import os

    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "clips"
    old = os.umask(0o022)
    try:
        res = runner.invoke(app, ["motions", "import", str(tmp_path / "nope.bvh"), "--out", str(out)])
        good = tmp_path / "squat.bvh"
        good.write_text(_squat_bvh(n=20)[0])
        ok = runner.invoke(app, ["motions", "import", str(good), "--out", str(out)])
    finally:
        os.umask(old)
    assert res.exit_code == 1 and "nope.bvh" in res.output
    assert "Imported 0 clip" not in res.output and "┏" not in res.output  # no empty table before the error
    assert ok.exit_code == 0, ok.output
    for name in ("import_summary.json", "squat.npz"):
        assert (out / name).stat().st_mode & 0o777 == 0o644, name  # not mkstemp's 0600
