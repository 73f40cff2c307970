"""BVH import: a CMU-style skeleton (y up, facing +z, centimetres, T-pose rest) retargets through the IK path."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_env.model import JOINT_NAMES, load_model
from motions.importers import detect_format, import_file
from motions.importers.bvh import BvhFormatError, load_bvh, parse_bvh
from motions.kinematics import foot_geom_ids, geom_bottoms

# name, parent, offset (cm), rotation channels (CMU order)
SKELETON = [
    ("Hips", None, (0, 0, 0)),
    ("LeftUpLeg", "Hips", (9, -5, 0)), ("LeftLeg", "LeftUpLeg", (0, -41, 0)), ("LeftFoot", "LeftLeg", (0, -42, 0)),
    ("LeftToeBase", "LeftFoot", (0, -5, 12)),
    ("RightUpLeg", "Hips", (-9, -5, 0)), ("RightLeg", "RightUpLeg", (0, -41, 0)), ("RightFoot", "RightLeg", (0, -42, 0)),
    ("RightToeBase", "RightFoot", (0, -5, 12)),
    ("Spine", "Hips", (0, 12, 0)), ("Spine1", "Spine", (0, 22, 0)), ("Neck", "Spine1", (0, 20, 0)), ("Head", "Neck", (0, 10, 0)),
    ("LeftShoulder", "Spine1", (4, 16, 0)), ("LeftArm", "LeftShoulder", (13, 0, 0)), ("LeftForeArm", "LeftArm", (26, 0, 0)),
    ("LeftHand", "LeftForeArm", (25, 0, 0)),
    ("RightShoulder", "Spine1", (-4, 16, 0)), ("RightArm", "RightShoulder", (-13, 0, 0)),
    ("RightForeArm", "RightArm", (-26, 0, 0)), ("RightHand", "RightForeArm", (-25, 0, 0)),
]
END_SITES = {"LeftToeBase": (0, 0, 4), "RightToeBase": (0, 0, 4), "Head": (0, 12, 0), "LeftHand": (8, 0, 0), "RightHand": (-8, 0, 0)}


def _hierarchy(skip: str | None = None) -> str:
    children: dict[str | None, list] = {}
    for name, parent, off in SKELETON:
        if name != skip:
            children.setdefault(parent, []).append((name, off))

    def block(name: str, off, depth: int, root: bool = False) -> str:
        pad = "  " * depth
        chans = "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if root else "CHANNELS 3 Zrotation Xrotation Yrotation"
        out = f"{pad}{'ROOT' if root else 'JOINT'} {name}\n{pad}{{\n{pad}  OFFSET {off[0]} {off[1]} {off[2]}\n{pad}  {chans}\n"
        for child, coff in children.get(name, []):
            out += block(child, coff, depth + 1)
        if name in END_SITES:
            e = END_SITES[name]
            out += f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET {e[0]} {e[1]} {e[2]}\n{pad}  }}\n"
        return out + f"{pad}}}\n"

    return "HIERARCHY\n" + block("Hips", (0, 0, 0), 0, root=True)


def _squat_bvh(n: int = 60, fps: float = 60.0, skip: str | None = None) -> tuple[str, np.ndarray]:
    """Knee bends: hip flexes by a, knee by 2a, ankle back by a; arms lowered to the sides. Returns (text, a)."""
    names = [s[0] for s in SKELETON if s[0] != skip]
    a = 0.6 * np.sin(np.linspace(0, np.pi, n)) ** 2  # radians
    values = np.zeros((n, 6 + 3 * (len(names) - 1)))
    leg = 41 + 42
    values[:, 1] = leg * np.cos(a) + 10  # hips height in cm: legs plus ankle-to-floor
    deg = np.degrees(a)
    for i, name in enumerate(names[1:]):
        c = 6 + 3 * i  # Zrotation, Xrotation, Yrotation
        if name.endswith("UpLeg"):
            values[:, c + 1] = -deg
        elif name.endswith("Leg"):
            values[:, c + 1] = 2 * deg
        elif name.endswith("Foot"):
            values[:, c + 1] = -deg
        elif name == "LeftArm":
            values[:, c] = -80
        elif name == "RightArm":
            values[:, c] = 80
    text = _hierarchy(skip) + f"MOTION\nFrames: {n}\nFrame Time: {1 / fps:.8f}\n"
    text += "\n".join(" ".join(f"{v:.5f}" for v in row) for row in values) + "\n"
    return text, a


def test_cmu_bvh_retargets_through_ik(tmp_path):
    text, a = _squat_bvh()
    path = tmp_path / "squat.bvh"
    path.write_text(text)
    assert detect_format(path) == "bvh"
    src = load_bvh(path)
    # y up -> z up keeps x: the CMU left side (+x) stays +x, the neck ends up above the hips
    assert src.positions["l_hip"][0, 0] > 0 > src.positions["r_hip"][0, 0]
    assert src.positions["neck"][0, 2] - src.positions["l_hip"][0, 2] > 40
    clip, report = import_file(path, use_cache=False)
    assert clip.n_frames == 30 and np.all(np.isfinite(clip.qpos))
    knee = clip.qpos[:, 7 + JOINT_NAMES.index("L_Knee_y")]
    hip = clip.qpos[:, 7 + JOINT_NAMES.index("L_Hip_y")]
    np.testing.assert_allclose(knee, 2 * a[::2], atol=0.12)
    np.testing.assert_allclose(hip, -a[::2], atol=0.12)
    standing = a[::2] < 0.05
    assert np.all((clip.qpos[standing, 2] > 0.8) & (clip.qpos[standing, 2] < 1.1))
    feet = geom_bottoms(load_model(), clip.qpos)[:, foot_geom_ids(load_model())]
    assert feet.min() > -0.02 and np.abs(feet.min(axis=1)).max() < 0.02  # feet stay on the floor throughout
    arm_down = clip.qpos[:, 7 + JOINT_NAMES.index("L_Shoulder_x")]
    assert np.all(arm_down < -0.9)  # the arms hang down like the source's


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t.replace("HIERARCHY", "HIERARCHIES"), "does not start with HIERARCHY"),
        (lambda t: t.rsplit(" ", 3)[0] + "\n", "values, found"),
        (lambda t: t.replace("Frame Time: ", "Frame Time: 0 #"), "frame time 0 s"),
        (lambda t: t.replace("CHANNELS 3 Zrotation", "CHANNELS 3 Wrotation", 1), "unknown channels"),
        (lambda t: t[: t.index("MOTION")] + t[t.index("MOTION"):].replace("0.00000", "zero", 1), "non-numeric"),
        (lambda t: t[: t.index("MOTION") - 40], "file ends inside the hierarchy"),
    ],
)
def test_malformed_bvh(tmp_path, edit, message):
    text, _ = _squat_bvh(n=4)
    path = tmp_path / "bad.bvh"
    path.write_text(edit(text))
    with pytest.raises(BvhFormatError) as err:
        load_bvh(path)
    assert str(path) in str(err.value) and message in str(err.value), str(err.value)


def test_missing_joint_is_named(tmp_path):
    text, _ = _squat_bvh(n=4, skip="LeftHand")
    path = tmp_path / "no_hand.bvh"
    path.write_text(text)
    with pytest.raises(BvhFormatError, match="no joint for l_wrist"):
        load_bvh(path)


def test_parse_counts_channels():
    text, _ = _squat_bvh(n=3)
    joints, values, frame_time = parse_bvh(text)
    assert len([j for j in joints if not j.end_site]) == len(SKELETON)
    assert values.shape == (3, 6 + 3 * (len(SKELETON) - 1)) and frame_time == pytest.approx(1 / 60)


def _renamed(tmp_path, names: dict[str, str], name: str = "rig.bvh"):
    text, _ = _squat_bvh(n=6)
    for old, new in names.items():
        text = text.replace(f"JOINT {old}\n", f"JOINT {new}\n").replace(f"ROOT {old}\n", f"ROOT {new}\n")
    path = tmp_path / name
    path.write_text(text)
    return path


MAKEHUMAN = {"Hips": "hip", "Spine": "abdomen", "Spine1": "chest", "LeftUpLeg": "lhip", "LeftLeg": "lknee",
             "LeftFoot": "lfoot", "LeftToeBase": "toe1-1.L", "RightUpLeg": "rhip", "RightLeg": "rknee",
             "RightFoot": "rfoot", "RightToeBase": "toe1-1.R", "LeftArm": "lshldr", "RightArm": "rshldr",
             "LeftForeArm": "lforearm", "RightForeArm": "rforearm", "LeftHand": "lhand", "RightHand": "rhand"}


def test_makehuman_rig_names_are_known(tmp_path):
    src = load_bvh(_renamed(tmp_path, MAKEHUMAN))
    cmu = load_bvh(_renamed(tmp_path, {}, "cmu.bvh"))
    for key in ("l_toe", "r_toe", "l_knee", "r_wrist"):
        np.testing.assert_allclose(src.positions[key], cmu.positions[key])


def test_an_unknown_toe_name_falls_back_to_what_hangs_below_the_foot(tmp_path):
    src = load_bvh(_renamed(tmp_path, {"LeftToeBase": "ball_l", "RightToeBase": "ball_r"}))
    cmu = load_bvh(_renamed(tmp_path, {}, "cmu.bvh"))
    np.testing.assert_allclose(src.positions["l_toe"], cmu.positions["l_toe"])


def test_a_joint_map_names_the_joints_of_any_rig(tmp_path):
    path = _renamed(tmp_path, {"LeftHand": "wrist_a", "RightHand": "wrist_b"})
    with pytest.raises(BvhFormatError, match="no joint for l_wrist .*--joint-map"):
        load_bvh(path)
    src = load_bvh(path, joint_map={"l_wrist": "wrist_a", "r_wrist": "wrist_b"})
    np.testing.assert_allclose(src.positions["l_wrist"], load_bvh(_renamed(tmp_path, {}, "c.bvh")).positions["l_wrist"])
    with pytest.raises(BvhFormatError, match="no joint named 'nope' for l_wrist"):
        load_bvh(path, joint_map={"l_wrist": "nope"})
    with pytest.raises(BvhFormatError, match="unknown keypoint 'l_hand'"):
        load_bvh(path, joint_map={"l_hand": "wrist_a"})
