"""BVH (CMU-style hierarchy) -> keypoints for retargeting.

Joint rotations follow each joint's CHANNELS order as intrinsic rotations in degrees; a joint with position
channels uses them as its translation, otherwise its OFFSET. BVH files are y up by convention (`up_axis="y"`);
units do not matter because the retargeter rescales by leg length. Keypoints are found by joint name (a user
joint map first, then CMU names, then common alternatives such as MakeHuman's); a foot with no toe joint of a known
name uses whatever joint or End Site hangs below it. Rest frames are unknown, so orientations are derived from the
keypoints.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motions.limits import MAX_BVH_DEPTH, check_frame_times, read_text
from motions.retarget import SourceMotion, limb_speeds

#: keypoint -> candidate joint names (lower case, tried in order): CMU's, common alternatives such as MakeHuman's
#: and the Daz/Poser names of the Daz-friendly CMU release (`lThigh`, `lShin`, `lFoot`, `lShldr`, `lForeArm`,
#: `lHand`; its toe is the End Site below the foot, its `lButtock` sits above the hip joint and is not one), and
#: Character Creator's (`CC_Base_L_Thigh`, ...).
NAMES = {
    "l_hip": ("leftupleg", "lefthip", "lhip", "l_hip", "leftthigh", "lthigh", "cc_base_l_thigh"),
    "l_knee": ("leftleg", "leftknee", "lknee", "l_knee", "leftshin", "lshin", "leftlowerleg", "cc_base_l_calf"),
    "l_ankle": ("leftfoot", "leftankle", "lankle", "l_ankle", "lfoot", "cc_base_l_foot"),
    "l_toe": ("lefttoebase", "lefttoe", "ltoe", "l_toe", "lefttoes", "toe1-1.l", "toes.l", "toe.l",
              "cc_base_l_toebase"),
    "neck": ("neck", "neck1", "lowerneck", "cc_base_necktwist01"),
    "head": ("head", "cc_base_head"),
    "l_shoulder": ("leftarm", "leftupperarm", "lshldr", "leftshoulder", "l_shoulder", "cc_base_l_upperarm"),
    "l_elbow": ("leftforearm", "leftelbow", "leftlowerarm", "lforearm", "l_elbow", "cc_base_l_forearm"),
    "l_wrist": ("lefthand", "leftwrist", "lhand", "l_wrist", "cc_base_l_hand"),
}


def _right(name: str) -> str:
    """The right-side twin of a left joint name: leftfoot, l_foot, lfoot (CMU, Poser), toe.l (MakeHuman) and
    cc_base_l_foot (Character Creator)."""
    if name.endswith(".l"):
        return name[:-2] + ".r"
    if "_l_" in name:
        return name.replace("_l_", "_r_")
    if "left" in name:
        return name.replace("left", "right")
    return "r" + name[1:]


for _k, _v in list(NAMES.items()):
    if _k.startswith("l_"):
        NAMES["r_" + _k[2:]] = tuple(_right(n) for n in _v)
Y_UP_TO_Z_UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


class BvhFormatError(ValueError):
    """A BVH file that cannot be read; the message names the file and the problem."""


@dataclass
class Joint:
    name: str
    parent: int
    offset: np.ndarray
    channels: list[str] = field(default_factory=list)
    end_site: bool = False


def parse_bvh(text: str, where: str = "BVH") -> tuple[list[Joint], np.ndarray, float]:
    """(joints in file order, motion values (T, n_channels), frame time in seconds)."""
    tokens = text.split()
    pos = 0

    def take() -> str:
        nonlocal pos
        if pos >= len(tokens):
            raise BvhFormatError(f"{where}: file ends inside the hierarchy")
        pos += 1
        return tokens[pos - 1]

    def number() -> float:
        tok = take()
        try:
            return float(tok)
        except ValueError:
            raise BvhFormatError(f"{where}: expected a number, got {tok!r}") from None

    if not tokens or tokens[0] != "HIERARCHY":
        raise BvhFormatError(f"{where}: does not start with HIERARCHY")
    take()
    joints: list[Joint] = []

    def line_of(index: int) -> int:
        """The 1-based line of token `index`, found by counting again (only for an error's message)."""
        seen = 0
        for number_, line in enumerate(text.splitlines(), 1):
            seen += len(line.split())
            if seen > index:
                return number_
        return text.count("\n") + 1

    def count(field: str) -> int:
        value = number()
        if not (np.isfinite(value) and value == int(value) and value >= 0):
            raise BvhFormatError(f"{where}:{line_of(pos - 1)}: {field}: expected a count (a whole number >= 0), "
                                 f"got {tokens[pos - 1]}")
        return int(value)

    def parse_joint(parent: int, end_site: bool, depth: int) -> None:
        name = "End Site" if end_site else take()
        if depth > MAX_BVH_DEPTH:
            raise BvhFormatError(f"{where}: joints nested more than {MAX_BVH_DEPTH} deep (at joint {name})")
        if end_site and take() != "Site":
            raise BvhFormatError(f"{where}: malformed End Site")
        if take() != "{":
            raise BvhFormatError(f"{where}: expected '{{' after joint {name}")
        if take() != "OFFSET":
            raise BvhFormatError(f"{where}: joint {name} lacks OFFSET")
        joint = Joint(name, parent, np.array([number(), number(), number()]), end_site=end_site)
        joints.append(joint)
        me = len(joints) - 1
        while True:
            tok = take()
            if tok == "}":
                return
            if tok == "CHANNELS" and not end_site:
                joint.channels = [take() for _ in range(count(f"CHANNELS of joint {name}"))]
                bad = [c for c in joint.channels if c[1:] not in ("position", "rotation") or c[0] not in "XYZ"]
                if bad:
                    raise BvhFormatError(f"{where}: joint {name} has unknown channels {bad}")
            elif tok == "JOINT" and not end_site:
                parse_joint(me, False, depth + 1)
            elif tok == "End" and not end_site:
                parse_joint(me, True, depth + 1)
            else:
                raise BvhFormatError(f"{where}: unexpected {tok!r} in joint {name}")

    if take() != "ROOT":
        raise BvhFormatError(f"{where}: HIERARCHY must begin with ROOT")
    parse_joint(-1, False, 0)
    if take() != "MOTION" or take() != "Frames:":
        raise BvhFormatError(f"{where}: expected 'MOTION' and 'Frames:' after the hierarchy")
    n_frames = count("Frames")
    if take() != "Frame" or take() != "Time:":
        raise BvhFormatError(f"{where}: expected 'Frame Time:'")
    frame_time = number()
    if n_frames < 2:
        raise BvhFormatError(f"{where}: needs at least 2 frames, got {n_frames}")
    check_frame_times(frame_time, where, BvhFormatError, repeats=n_frames - 1)
    n_channels = sum(len(j.channels) for j in joints)
    rest = tokens[pos:]
    if len(rest) != n_frames * n_channels:
        raise BvhFormatError(f"{where}: {n_frames} frames x {n_channels} channels need {n_frames * n_channels} "
                             f"values, found {len(rest)}")
    try:
        values = np.array(rest, dtype=np.float64).reshape(n_frames, n_channels)
    except ValueError:
        raise BvhFormatError(f"{where}: motion data contains non-numeric values") from None
    except MemoryError:
        raise BvhFormatError(f"{where}: motion data too large to load into memory") from None
    if not np.all(np.isfinite(values)):
        raise BvhFormatError(f"{where}: motion data contains NaN or inf")
    return joints, values, frame_time


def forward_kinematics(joints: list[Joint], values: np.ndarray) -> np.ndarray:
    """(T, n_joints, 3) world positions in the file's own frame and units."""
    n = values.shape[0]
    pos = np.zeros((n, len(joints), 3))
    rots: list[Rotation] = []
    col = 0
    for i, j in enumerate(joints):
        trans = np.repeat(j.offset[None], n, axis=0)
        rot_axes, rot_cols = "", []
        for c in j.channels:
            if c.endswith("position"):
                trans[:, "XYZ".index(c[0])] = values[:, col]
            else:
                rot_axes += c[0]
                rot_cols.append(col)
            col += 1
        local = Rotation.from_euler(rot_axes, values[:, rot_cols], degrees=True) if rot_axes else Rotation.identity(n)
        if j.parent < 0:
            pos[:, i] = trans
            rots.append(local)
        else:
            pos[:, i] = pos[:, j.parent] + rots[j.parent].apply(trans)
            rots.append(rots[j.parent] * local)
    return pos


def _find(joints: list[Joint], key: str) -> int | None:
    names = [j.name.split(":")[-1].lower() for j in joints]
    for cand in NAMES[key]:
        if cand in names:
            return names.index(cand)
    return None


def load_bvh(path: str | Path, up_axis: str = "y", joint_map: dict[str, str] | None = None,
             fps: float | None = None) -> SourceMotion:
    """Keypoints of a BVH clip in our z-up world; `joint_map` names the joint of any keypoint (l_hip, r_toe, head,
    ...) for a rig whose names are not known here. `fps` overrides the header's frame time, for files whose header
    is wrong (the Daz-friendly CMU salsa takes say 120 fps and are 60)."""
    path = Path(path)
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    joint_map = dict(joint_map or {})
    unknown = sorted(set(joint_map) - set(NAMES))
    if unknown:
        raise BvhFormatError(f"joint map: unknown keypoint {unknown[0]!r} (keypoints: {', '.join(NAMES)})")
    text = read_text(path, BvhFormatError)
    joints, values, header_time = parse_bvh(text, str(path))
    frame_time = header_time
    if fps is not None:
        frame_time = 1.0 / fps
    world = forward_kinematics(joints, values)
    if up_axis == "y":
        world = world @ Y_UP_TO_Z_UP.T
    idx: dict[str, int] = {}
    names = [j.name for j in joints]
    for key in NAMES:
        if key in joint_map:
            if joint_map[key] not in names:
                raise BvhFormatError(f"{path}: joint map: no joint named {joint_map[key]!r} for {key}")
            idx[key] = names.index(joint_map[key])
            continue
        found = _find(joints, key)
        if found is None and key in ("l_toe", "r_toe", "head"):  # the End Site below the neck, or below the foot
            parent = idx.get(key[:2] + "ankle" if key != "head" else "neck")  # any joint there too: the foot's tip
            below = [i for i, j in enumerate(joints) if j.parent == parent and parent is not None]
            found = next((i for i in below if joints[i].end_site), below[0] if below and key != "head" else None)
        if found is None:
            raise BvhFormatError(f"{path}: no joint for {key} (tried {', '.join(NAMES[key])}; name it with a joint "
                                 f"map, e.g. `fbcpr motions import --joint-map map.yaml` with `{key}: JointName`)")
        idx[key] = found
    positions = {k: world[:, i] for k, i in idx.items()}
    skip = leading_rest_frames(positions, frame_time)
    positions = {k: v[skip:] for k, v in positions.items()}
    note = f" (first {skip} frame(s), a rest pose apart from the motion, left out)" if skip else ""
    rate = f" at {fps:g} fps (the header says {1.0 / header_time:g})" if fps is not None else ""
    return SourceMotion(name=path.stem, positions=positions, times=np.arange(values.shape[0] - skip) * frame_time,
                        source=f"BVH {path.name}{rate}{note}", license="see the license of the source dataset")


#: Pelvis-relative keypoint speed, in leg lengths per second, above which a leading frame is no body's motion.
REST_BLEND_SPEED = 10.0


def leading_rest_frames(positions: dict[str, np.ndarray], frame_time: float = 1 / 120) -> int:
    """How many first frames stand apart from the motion: some exporters put the rig's rest pose (a T-pose)
    before the take. At the origin (Character Creator), the pelvis jumps more than half a leg length to the next
    frame; in place (the Daz-friendly release), the limbs swing from the T-pose into the take's first pose within
    a few frames, faster than REST_BLEND_SPEED leg lengths a second relative to the pelvis (kicks and spins reach
    that inside the CMU takes; none starts with one). Only leading frames: a jump inside the take stays an error of
    the clip."""
    pelvis = (positions["l_hip"] + positions["r_hip"]) / 2
    leg = np.median(np.linalg.norm(positions["l_hip"] - positions["l_knee"], axis=1) +
                    np.linalg.norm(positions["l_knee"] - positions["l_ankle"], axis=1))
    times = np.arange(len(pelvis)) * frame_time
    jumps = (np.linalg.norm(np.diff(pelvis, axis=0), axis=1) > 0.5 * leg) | \
        (limb_speeds(positions, times) > REST_BLEND_SPEED)
    skip = 0
    while skip < len(jumps) - 2 and jumps[skip]:
        skip += 1
    return skip
