"""The Daz-friendly BVH rig of the CMU captures (`hip`, `abdomen`, `lThigh`, ...; a T-pose before each take), the
frame-rate override for files whose header is wrong, and the quality report of an import."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from fbcpr.cli.app import app
from motions.importers import import_file
from motions.importers.bvh import leading_rest_frames, load_bvh
from motions.retarget import QUALITY_LIMITS, RetargetReport

CMU = Path(__file__).parents[1].parent / "shared" / "mocap" / "cmu"
DAZ = CMU / "bvh-daz"
needs_daz = pytest.mark.skipif(not (DAZ / "martial" / "04.bvh").is_file(),
                               reason=f"Daz-rig captures not found in {DAZ}")


@needs_daz
def test_a_daz_rig_take_imports_into_a_standing_clip_with_its_feet_on_the_floor():
    src = load_bvh(DAZ / "martial" / "04.bvh")
    assert "rest pose" in src.source  # the T-pose and its swing into the take are left out
    clip, report = import_file(DAZ / "martial" / "04.bvh", use_cache=False)
    assert np.all(np.isfinite(clip.qpos))
    assert 10.0 < clip.seconds < 11.5  # 1,317 frames at 120 fps, less the leading ones
    assert 0.75 < np.median(clip.qpos[:, 2]) < 1.05  # pelvis height of a standing body
    assert report.contact_share > 0.5  # feet found on the floor (the clip's lowest glitch frame is no floor)
    assert report.max_contact_gap < 0.03 and report.max_penetration < 0.02
    assert report.foot_slide < QUALITY_LIMITS["foot slide"]
    assert (clip.qpos[:, 2] > 0.5).all()  # no frame lying on the floor


@needs_daz
def test_the_frame_rate_override_doubles_and_halves_the_duration():
    header = load_bvh(DAZ / "salsa" / "05.bvh")
    slow = load_bvh(DAZ / "salsa" / "05.bvh", fps=60)  # the source says its salsa is 60 fps, the header 120
    assert slow.times[-1] == pytest.approx(2 * header.times[-1], rel=0.01)
    assert "at 60 fps (the header says 120)" in slow.source
    base, _ = import_file(CMU / "bvh" / "002_03.bvh", use_cache=False)  # a 60 fps header
    fast, _ = import_file(CMU / "bvh" / "002_03.bvh", use_cache=False, fps=120)
    slower, _ = import_file(CMU / "bvh" / "002_03.bvh", use_cache=False, fps=30)
    assert fast.seconds == pytest.approx(base.seconds / 2, abs=0.05)
    assert slower.seconds == pytest.approx(base.seconds * 2, abs=0.05)
    with pytest.raises(ValueError, match="fps"):
        import_file(CMU / "bvh" / "002_03.bvh", use_cache=False, fps=0)


def test_a_t_pose_that_swings_into_the_take_in_place_is_left_out():
    """The Daz-friendly release starts each take with a T-pose where the take starts: no pelvis jump, but the arms
    drop from horizontal to the first pose within a frame or two, faster than any body moves them."""
    t = np.arange(40)[:, None] * np.array([0.0, 0.01, 0.0])  # walking 1 cm a frame at 120 fps
    pos = {"l_hip": t + [0.1, 0, 0.9], "r_hip": t + [-0.1, 0, 0.9], "l_knee": t + [0.1, 0, 0.45],
           "l_ankle": t + [0.1, 0, 0.0], "l_wrist": t + [0.2, 0, 0.8]}
    assert leading_rest_frames(pos, 1 / 120) == 0
    posed = {k: v.copy() for k, v in pos.items()}
    posed["l_wrist"][0] = t[0] + [0.8, 0, 1.4]  # arm out in the T-pose, then halfway down, then the take
    posed["l_wrist"][1] = t[1] + [0.5, 0, 1.1]
    assert leading_rest_frames(posed, 1 / 120) == 2
    assert leading_rest_frames(posed, 1.0) == 0  # the same swing over two seconds is a body's


def test_the_quality_flags_name_what_is_past_its_limit():
    clean = RetargetReport(name="a", frames=100, seconds=3.3, foot_slide=0.1, contact_share=0.9, peak_limb_speed=8)
    assert clean.flags() == []
    bad = RetargetReport(name="b", frames=100, seconds=3.3, foot_slide=0.5, max_penetration=0.05,
                         clipped={"L_Knee_x": 30}, contact_share=0.05, peak_limb_speed=50)
    assert bad.flags() == ["foot slide", "penetration", "joint limits", "glitch", "few contacts"]


@needs_daz
def test_import_with_fps_writes_the_quality_of_each_take_beside_the_clips(tmp_path):
    out = tmp_path / "clips"
    res = CliRunner().invoke(app, ["motions", "import", str(CMU / "bvh" / "002_03.bvh"), "--out", str(out),
                                   "--fps", "30", "--no-cache"])
    assert res.exit_code == 0, res.output
    entry = json.loads((out / "import_summary.json").read_text())["clips"][0]
    assert entry["seconds"] == pytest.approx(2 * 85 / 60, abs=0.1)  # 86 frames read at 30 fps, not 60
    for key in ("foot_slide_m_s", "max_foot_penetration_m", "clipped_joint_frames", "contact_share",
                "peak_limb_speed_legs_s", "flags"):
        assert key in entry
    assert "limbs" in res.output and "flags" in res.output
    res = CliRunner().invoke(app, ["motions", "import", str(CMU / "bvh" / "002_03.bvh"), "--out", str(out),
                                   "--fps", "-5"])
    assert res.exit_code != 0 and "--fps" in res.output
