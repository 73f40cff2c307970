"""ASF/AMC import (CMU's native format) and CMU's BVH takes on a Character Creator rig: forward kinematics by
the Acclaim convention, clear errors, and the real captures in ../shared retargeted into plausible clips."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from fbcpr.cli.app import app
from motions.formats import UnknownFormatError, detect_format
from motions.importers import import_file
from motions.importers.asfamc import AsfAmcFormatError, bone_starts, load_amc, parse_amc, parse_asf
from motions.importers.bvh import NAMES, load_bvh

CMU = Path(__file__).parents[1].parent / "shared" / "mocap" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "asfamc" / "02.asf").is_file(), reason=f"CMU captures not found in {CMU}")

# bone, parent, direction, length, axis (deg), dof: a small CMU-named skeleton, y up, facing +z
BONES = [
    ("lhipjoint", "root", (1, -1, 0), 1.4, (0, 0, 0), ""), ("lfemur", "lhipjoint", (0, -1, 0), 8.0, (0, 0, 20), "rx ry rz"),
    ("ltibia", "lfemur", (0, -1, 0), 8.0, (0, 0, 20), "rx"), ("lfoot", "ltibia", (0, 0, 1), 2.0, (0, 0, 0), "rx rz"),
    ("ltoes", "lfoot", (0, 0, 1), 1.0, (0, 0, 0), "rx"),
    ("rhipjoint", "root", (-1, -1, 0), 1.4, (0, 0, 0), ""), ("rfemur", "rhipjoint", (0, -1, 0), 8.0, (0, 0, -20), "rx ry rz"),
    ("rtibia", "rfemur", (0, -1, 0), 8.0, (0, 0, -20), "rx"), ("rfoot", "rtibia", (0, 0, 1), 2.0, (0, 0, 0), "rx rz"),
    ("rtoes", "rfoot", (0, 0, 1), 1.0, (0, 0, 0), "rx"),
    ("lowerback", "root", (0, 1, 0), 2.0, (0, 0, 0), "rx ry rz"), ("thorax", "lowerback", (0, 1, 0), 4.0, (0, 0, 0), "rx"),
    ("lowerneck", "thorax", (0, 1, 0), 1.5, (0, 0, 0), "rx"), ("head", "lowerneck", (0, 1, 0), 1.5, (0, 0, 0), "rx"),
    ("lclavicle", "thorax", (1, 0, 0), 2.0, (0, 0, 0), ""), ("lhumerus", "lclavicle", (1, 0, 0), 4.5, (0, 0, 0), "rx ry rz"),
    ("lradius", "lhumerus", (1, 0, 0), 3.5, (0, 0, 0), "rx"), ("lwrist", "lradius", (1, 0, 0), 1.0, (0, 0, 0), ""),
    ("rclavicle", "thorax", (-1, 0, 0), 2.0, (0, 0, 0), ""), ("rhumerus", "rclavicle", (-1, 0, 0), 4.5, (0, 0, 0), "rx ry rz"),
    ("rradius", "rhumerus", (-1, 0, 0), 3.5, (0, 0, 0), "rx"), ("rwrist", "rradius", (-1, 0, 0), 1.0, (0, 0, 0), ""),
]


def asf_text() -> str:
    out = [":version 1.10", ":name test", ":units", "  mass 1.0", "  length 0.45", "  angle deg",
           ":root", "   order TX TY TZ RX RY RZ", "   axis XYZ", "   position 0 0 0", "   orientation 0 0 0", ":bonedata"]
    for i, (name, _, d, length, axis, dof) in enumerate(BONES, 1):
        out += ["  begin", f"     id {i}", f"     name {name}", f"     direction {d[0]} {d[1]} {d[2]}",
                f"     length {length}", f"     axis {axis[0]} {axis[1]} {axis[2]} XYZ"]
        if dof:
            out += [f"    dof {dof}", "    limits " + "\n           ".join("(-180.0 180.0)" for _ in dof.split())]
        out += ["  end"]
    children: dict[str, list[str]] = {}
    for name, parent, *_ in BONES:
        children.setdefault(parent, []).append(name)
    out += [":hierarchy", "  begin"] + [f"    {p} {' '.join(c)}" for p, c in children.items()] + ["  end"]
    return "\n".join(out) + "\n"


def amc_text(frames: int, femur_rx: float = 0.0, root_dz: float = 0.05) -> str:
    out = ["#!OML:ASF test.asf", ":FULLY-SPECIFIED", ":DEGREES"]
    for t in range(frames):
        out += [str(t + 1), f"root 0 17.4 {root_dz * t} 0 0 0"]
        for name, _, _, _, _, dof in BONES:
            if dof:
                values = ["0"] * len(dof.split())
                if name == "lfemur":
                    values[0] = str(femur_rx)
                out.append(f"{name} {' '.join(values)}")
    return "\n".join(out) + "\n"


@pytest.fixture
def cmu_pair(tmp_path):
    (tmp_path / "07.asf").write_text(asf_text())
    (tmp_path / "07_01.amc").write_text(amc_text(40))
    return tmp_path


def test_rest_pose_bones_follow_their_directions():
    sk = parse_asf(asf_text())
    root, dofs = parse_amc(amc_text(2, root_dz=0.0), sk)
    starts = bone_starts(sk, root, dofs)
    d = np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    np.testing.assert_allclose(starts["lfemur"][0], [0, 17.4, 0] + 1.4 * d, atol=1e-9)
    np.testing.assert_allclose(starts["ltibia"][0] - starts["lfemur"][0], [0, -8, 0], atol=1e-9)


def test_a_dof_turns_about_the_bone_axis():
    """femur rx = 40 deg on a bone whose axis is turned 20 deg about z: the knee swings about that turned x axis
    (C M C^-1), not about the world's x."""
    sk = parse_asf(asf_text())
    root, dofs = parse_amc(amc_text(2, femur_rx=40.0), sk)
    starts = bone_starts(sk, root, dofs)
    axis = Rotation.from_euler("z", 20, degrees=True).apply([1.0, 0.0, 0.0])
    expect = Rotation.from_rotvec(np.deg2rad(40) * axis).apply([0.0, -8.0, 0.0])
    np.testing.assert_allclose(starts["ltibia"][0] - starts["lfemur"][0], expect, atol=1e-9)


def test_an_amc_beside_its_skeleton_imports(cmu_pair):
    assert detect_format(cmu_pair / "07_01.amc") == "amc"
    src = load_amc(cmu_pair / "07_01.amc")
    assert src.times[1] == pytest.approx(1 / 120)
    head, ankle = src.positions["head"][0], src.positions["l_ankle"][0]
    assert head[2] - ankle[2] > 15  # y up in the file, z up here
    clip, report = import_file(cmu_pair / "07_01.amc", use_cache=False)
    assert clip.fps == 30 and clip.n_frames == 10 and report.foot_slide >= 0.0


def test_asfamc_errors_name_the_file_and_line(tmp_path, cmu_pair):
    with pytest.raises(UnknownFormatError, match="ASF skeleton, not a motion"):
        detect_format(cmu_pair / "07.asf")
    lone = tmp_path / "lone"
    lone.mkdir()
    (lone / "09_01.amc").write_text(amc_text(3))
    with pytest.raises(AsfAmcFormatError, match=r"09_01.amc: needs its ASF skeleton.*--skeleton"):
        load_amc(lone / "09_01.amc")
    bad = amc_text(3).replace("ltibia 0", "ltibia 0 0", 1)
    with pytest.raises(AsfAmcFormatError, match=r"AMC:\d+: ltibia has 2 values, the skeleton gives it 1"):
        parse_amc(bad, parse_asf(asf_text()))
    with pytest.raises(AsfAmcFormatError, match=r"AMC:\d+: bone 'tail' is not in the skeleton"):
        parse_amc(amc_text(3) + "tail 1\n", parse_asf(asf_text()))
    with pytest.raises(AsfAmcFormatError, match=r"ASF:\d+: length: expected numbers, got 'long'"):
        parse_asf(asf_text().replace("length 8.0", "length long", 1))
    with pytest.raises(AsfAmcFormatError, match="'ghost' is not in the :hierarchy"):
        parse_asf(asf_text().replace("name lwrist", "name ghost"))


def test_the_cli_reads_skeletons_with_their_motions(cmu_pair, tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_CACHE_DIR", str(tmp_path / "cache"))
    res = CliRunner().invoke(app, ["motions", "import", str(cmu_pair / "07_01.amc"), str(cmu_pair / "07.asf"),
                                   "--out", str(tmp_path / "clips")])
    assert res.exit_code == 0, res.output
    assert "skeletons read with their motions, not imported: 07.asf" in res.output
    (entry,) = json.loads((tmp_path / "clips" / "import_summary.json").read_text())["clips"]
    assert entry["clip"] == "07_01.npz" and "foot_slide_m_s" in entry


def test_character_creator_joint_names_are_known():
    assert "cc_base_l_thigh" in NAMES["l_hip"] and "cc_base_r_thigh" in NAMES["r_hip"]
    assert "cc_base_r_toebase" in NAMES["r_toe"]


@needs_cmu
def test_cmu_walks_in_both_formats_retarget_into_walks():
    """Subject 02's first take as native AMC and as a BVH on a Character Creator rig: both walk forward about as
    far, stand upright and keep their feet on the floor."""
    amc, amc_report = import_file(CMU / "asfamc" / "02_01.amc", use_cache=False)
    bvh, bvh_report = import_file(CMU / "bvh" / "002_01.bvh", use_cache=False)
    for clip, report in ((amc, amc_report), (bvh, bvh_report)):
        travel = np.linalg.norm(clip.qpos[-1, :2] - clip.qpos[0, :2])
        assert 1.5 < travel < 5.0, travel
        assert 0.8 < np.median(clip.qpos[:, 2]) < 1.1  # pelvis height of a standing walk
        assert report.max_penetration < 0.02 and report.foot_slide < 0.3
    src = load_bvh(CMU / "bvh" / "007_01.bvh")
    assert (src.positions["head"][:, 2] > src.positions["l_ankle"][:, 2] + 1.0).all()


@needs_cmu
def test_twists_the_source_does_not_give_stay_near_rest():
    """ASF/AMC and BVH give no head or foot orientations: their twist joints follow the posture task to rest
    instead of an identity target that faced the world's +x and held them at their stops for whole takes."""
    from humanoid_env.model import JOINT_NAMES

    twists = [JOINT_NAMES.index(n) for n in ("Head_z", "Neck_z", "L_Ankle_z", "R_Ankle_z")]
    for path in (CMU / "asfamc" / "02_02.amc", CMU / "bvh" / "007_03.bvh"):
        clip, report = import_file(path, use_cache=False)
        mean = np.degrees(np.abs(clip.qpos[:, 7:][:, twists]).mean(axis=0))
        assert (mean < 15.0).all(), (path.name, mean)
        assert all(report.at_limits.get(n, 0) < 0.1 * report.frames for n in ("Head_z", "Neck_z")), report.at_limits
        assert report.keypoint_error < 0.01, report.keypoint_error


def test_a_rest_frame_before_the_take_is_left_out():
    """Some exporters put the rig's T-pose at the origin before the take: the pelvis jumps far to frame 1."""
    from motions.importers.bvh import leading_rest_frames

    t = np.arange(20)[:, None] * np.array([0.0, 0.02, 0.0])  # walking 2 cm a frame, legs 0.9 long
    pos = {"l_hip": t + [0.1, 0, 0.9], "r_hip": t + [-0.1, 0, 0.9], "l_knee": t + [0.1, 0, 0.45],
           "l_ankle": t + [0.1, 0, 0.0]}
    assert leading_rest_frames(pos) == 0
    moved = {k: v.copy() for k, v in pos.items()}
    for v in moved.values():
        v[0] -= [0.0, 2.0, 0.0]  # frame 0 two metres back
    assert leading_rest_frames(moved) == 1
    inside = {k: v.copy() for k, v in pos.items()}
    for v in inside.values():
        v[10:] += [0.0, 2.0, 0.0]  # a jump inside the take is the clip's error, not a rest frame
    assert leading_rest_frames(inside) == 0


@needs_cmu
def test_a_character_creator_take_with_a_rest_frame_imports():
    src = load_bvh(CMU / "bvh" / "007_03.bvh")
    assert "rest pose" in src.source
    clip, report = import_file(CMU / "bvh" / "007_03.bvh", use_cache=False)
    assert np.linalg.norm(clip.qpos[-1, :2] - clip.qpos[0, :2]) > 2.0 and report.foot_slide < 0.3


def test_a_bone_that_translates_is_refused():
    with pytest.raises(AsfAmcFormatError, match=r"ASF:\d+: dof 'tx' is not read here"):
        parse_asf(asf_text().replace("dof rx ry rz", "dof rx ry tx", 1))
