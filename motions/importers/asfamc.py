"""ASF/AMC (the Acclaim format of the CMU motion capture database) -> keypoints for retargeting.

The ASF file is the skeleton: each bone's rest direction (in world axes) and length, the axis of its local frame
and its degrees of freedom. The AMC file gives, frame by frame, the root's position and orientation and each
bone's dof values in degrees. By the Acclaim convention a bone's world rotation is its parent's times C M C^-1
(C: the bone's axis rotation, M: the frame's dof rotation, both static-axis Euler angles in the order given) and
its end is its start plus that rotation applied to direction x length. Keypoints are bone starts (the hip is
where the femur starts). CMU data is y up and recorded at 120 fps; AMC files do not state their rate.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from motions.importers.bvh import Y_UP_TO_Z_UP
from motions.limits import read_text
from motions.retarget import KEYPOINTS, SourceMotion

#: Frames per second of an AMC file (the CMU database records at 120 Hz; the format has no field for it).
AMC_FPS = 120.0
#: At most this many frames are read from one AMC file (an hour at 120 fps): bounds memory on a damaged file.
MAX_FRAMES = 432_000

#: keypoint -> the CMU bone whose start it is.
CMU_BONES = {
    "l_hip": "lfemur", "l_knee": "ltibia", "l_ankle": "lfoot", "l_toe": "ltoes",
    "r_hip": "rfemur", "r_knee": "rtibia", "r_ankle": "rfoot", "r_toe": "rtoes",
    "neck": "lowerneck", "head": "head",
    "l_shoulder": "lhumerus", "l_elbow": "lradius", "l_wrist": "lwrist",
    "r_shoulder": "rhumerus", "r_elbow": "rradius", "r_wrist": "rwrist",
}
#: The rotation dofs a bone may have (CMU bones have no translation or length dofs).
ROTATION_DOFS = ("rx", "ry", "rz")


class AsfAmcFormatError(ValueError):
    """An ASF skeleton or AMC motion that cannot be read; the message names the file, line and problem."""


@dataclass
class Bone:
    name: str
    direction: np.ndarray  # (3,) unit vector in world axes, rest pose
    length: float
    axis: np.ndarray  # (3, 3) the bone's local frame C
    dof: list[str] = field(default_factory=list)  # e.g. ["rx", "rz"]
    parent: str = "root"


@dataclass
class Skeleton:
    bones: dict[str, Bone]  # in hierarchy order: every parent before its children
    root_order: list[str]  # the AMC root line's channels, e.g. TX TY TZ RX RY RZ
    root_axis: np.ndarray  # (3, 3)


def _euler(order: str, degrees: np.ndarray) -> np.ndarray:
    """Rotation matrices of static-axis Euler angles applied in `order` (e.g. "XYZ"), degrees (..., 3)."""
    return Rotation.from_euler(order.lower(), degrees, degrees=True).as_matrix()


def _floats(parts: list[str], where: str, what: str) -> np.ndarray:
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise AsfAmcFormatError(f"{where}: {what}: expected numbers, got {' '.join(parts)!r}") from None
    if not np.all(np.isfinite(values)):
        raise AsfAmcFormatError(f"{where}: {what}: values must be finite, got {' '.join(parts)!r}")
    return values


def parse_asf(text: str, where: str = "ASF") -> Skeleton:
    """The skeleton of an ASF file: bones with their rest geometry and dofs, linked by its :hierarchy."""
    section, bones = "", {}
    current: dict[str, Any] | None = None
    root_order, root_axis = ["TX", "TY", "TZ", "RX", "RY", "RZ"], np.eye(3)
    angle_unit = "deg"
    parents: dict[str, str] = {}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        at = f"{where}:{n}"
        if line.startswith(":"):
            section, rest = line[1:].split(maxsplit=1)[0], line[1:].split()[1:]
            if section == "units" and rest:
                raise AsfAmcFormatError(f"{at}: :units takes its values on the following lines")
            continue
        parts = line.split()
        key = parts[0].lower()
        if section == "units" and key == "angle":
            angle_unit = parts[1].lower() if len(parts) > 1 else ""
            if angle_unit not in ("deg", "rad"):
                raise AsfAmcFormatError(f"{at}: units angle must be deg or rad, got {angle_unit!r}")
        elif section == "root" and key == "order":
            root_order = [p.upper() for p in parts[1:]]
        elif section == "root" and key == "orientation":
            root_axis = _euler("XYZ", _floats(parts[1:4], at, "root orientation"))
        elif section == "bonedata":
            if key == "begin":
                current = {"line": at}
            elif key == "end":
                if current is None or "name" not in current:
                    raise AsfAmcFormatError(f"{at}: a bone without a name")
                missing = [k for k in ("direction", "length") if k not in current]
                if missing:
                    raise AsfAmcFormatError(f"{at}: bone {current['name']!r} has no {missing[0]}")
                bones[current["name"]] = Bone(current["name"], current["direction"], current["length"],
                                              current.get("axis", np.eye(3)), current.get("dof", []))
                current = None
            elif current is not None:
                if key == "name":
                    current["name"] = parts[1]
                elif key == "direction":
                    d = _floats(parts[1:4], at, "direction")
                    norm = np.linalg.norm(d)
                    current["direction"] = d / norm if norm > 0 else d
                elif key == "length":
                    length = _floats(parts[1:2], at, "length")[0]
                    if length < 0:
                        raise AsfAmcFormatError(f"{at}: length must be >= 0, got {length}")
                    current["length"] = length
                elif key == "axis":
                    order = parts[4] if len(parts) > 4 else "XYZ"
                    if sorted(order.upper()) != ["X", "Y", "Z"]:
                        raise AsfAmcFormatError(f"{at}: axis order must be a permutation of XYZ, got {order!r}")
                    current["axis"] = _euler(order, _floats(parts[1:4], at, "axis"))
                elif key == "dof":
                    dof = [p.lower() for p in parts[1:]]
                    unknown = [d for d in dof if d not in ROTATION_DOFS]
                    if unknown:
                        raise AsfAmcFormatError(f"{at}: dof {unknown[0]!r} is not read here (only rotations: rx ry "
                                                "rz; a bone that translates or stretches would be posed wrong)")
                    current["dof"] = dof
        elif section == "hierarchy" and key not in ("begin", "end"):
            for child in parts[1:]:
                parents[child] = parts[0]
    if not bones:
        raise AsfAmcFormatError(f"{where}: no :bonedata (is it an ASF skeleton file?)")
    if angle_unit != "deg":
        raise AsfAmcFormatError(f"{where}: units angle rad is not supported (CMU files use deg)")
    orphans = sorted(set(bones) - set(parents))
    if orphans:
        raise AsfAmcFormatError(f"{where}: bone {orphans[0]!r} is not in the :hierarchy")
    ordered: dict[str, Bone] = {}
    while len(ordered) < len(bones):  # parents first: the hierarchy lists them in any order
        ready = [b for b in bones if b not in ordered and parents[b] in ("root", *ordered)]
        if not ready:
            raise AsfAmcFormatError(f"{where}: the :hierarchy has a loop or an unknown parent")
        for b in ready:
            bones[b].parent = parents[b]
            ordered[b] = bones[b]
    return Skeleton(ordered, root_order, root_axis)


def parse_amc(text: str, skeleton: Skeleton, where: str = "AMC") -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(root values (T, len(root order)), {bone: dof values (T, len(dof))}); a bone a frame leaves out is 0."""
    widths = {name: len(b.dof) for name, b in skeleton.bones.items()}
    frames: list[dict[str, list[str]]] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ":")):
            continue
        parts = line.split()
        if len(parts) == 1 and parts[0].isdigit():
            if len(frames) >= MAX_FRAMES:
                raise AsfAmcFormatError(f"{where}:{n}: more than {MAX_FRAMES:,} frames")
            frames.append({})
            continue
        if not frames:
            raise AsfAmcFormatError(f"{where}:{n}: bone values before the first frame number")
        name = parts[0]
        if name != "root" and name not in widths:
            raise AsfAmcFormatError(f"{where}:{n}: bone {name!r} is not in the skeleton")
        want = len(skeleton.root_order) if name == "root" else widths[name]
        if len(parts) - 1 != want:
            raise AsfAmcFormatError(f"{where}:{n}: {name} has {len(parts) - 1} values, the skeleton gives it {want}")
        frames[-1][name] = parts[1:]
    if len(frames) < 2:
        raise AsfAmcFormatError(f"{where}: needs at least 2 frames, got {len(frames)}")
    missing = [i + 1 for i, f in enumerate(frames) if "root" not in f]
    if missing:
        raise AsfAmcFormatError(f"{where}: frame {missing[0]} has no root line")
    root = np.stack([_floats(f["root"], where, "root") for f in frames])
    dofs = {name: np.stack([_floats(f[name], where, name) if name in f else np.zeros(w) for f in frames])
            for name, w in widths.items() if w}
    return root, dofs


def bone_starts(skeleton: Skeleton, root: np.ndarray, dofs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """World position (T, 3) of the start of every bone, and of "root", for each frame."""
    order = skeleton.root_order
    t = len(root)
    trans = np.zeros((t, 3))
    angles = np.zeros((t, 3))
    for i, channel in enumerate(order):
        axis = "XYZ".index(channel[1])
        (trans if channel[0] == "T" else angles)[:, axis] = root[:, i]
    rot_order = "".join(c[1] for c in order if c[0] == "R") or "XYZ"
    c = skeleton.root_axis
    world_rot = {"root": c @ _euler(rot_order, angles[:, ["XYZ".index(a) for a in rot_order]]) @ c.T}
    ends = {"root": trans}
    starts = {"root": trans}
    for name, bone in skeleton.bones.items():
        motion = np.broadcast_to(np.eye(3), (t, 3, 3))
        if bone.dof:
            motion = _euler("".join(d[1] for d in bone.dof).upper(), dofs[name])
        rot = world_rot[bone.parent] @ bone.axis @ motion @ bone.axis.T
        world_rot[name] = rot
        starts[name] = ends[bone.parent]
        ends[name] = starts[name] + rot @ (bone.direction * bone.length)
    return starts


def find_skeleton(amc: Path) -> Path:
    """The ASF beside an AMC: CMU names motions `<subject>_<take>.amc` beside `<subject>.asf`; else the only ASF
    in the folder."""
    named = amc.with_name(amc.stem.split("_")[0] + ".asf")
    if named.is_file():
        return named
    found = sorted(amc.parent.glob("*.asf"))
    if len(found) == 1:
        return found[0]
    why = "none" if not found else f"{len(found)} ({', '.join(p.name for p in found)})"
    raise AsfAmcFormatError(f"{amc}: needs its ASF skeleton: no {named.name} beside it, and the folder holds {why}; "
                            "name it with --skeleton")


def load_amc(path: str | Path, skeleton: str | os.PathLike | None = None, up_axis: str = "y",
             joint_map: dict[str, str] | None = None, fps: float = AMC_FPS) -> SourceMotion:
    """Keypoints of an AMC motion on its ASF skeleton (found beside it unless given) in our z-up world;
    `joint_map` names the bone whose start is a keypoint, for skeletons whose bones are not CMU's."""
    path = Path(path)
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    unknown = sorted(set(joint_map or {}) - set(KEYPOINTS))
    if unknown:
        raise AsfAmcFormatError(f"joint map: unknown keypoint {unknown[0]!r} (keypoints: {', '.join(KEYPOINTS)})")
    asf = Path(skeleton) if skeleton is not None else find_skeleton(path)
    bones = parse_asf(read_text(asf, AsfAmcFormatError), str(asf))
    root, dofs = parse_amc(read_text(path, AsfAmcFormatError), bones, str(path))
    starts = bone_starts(bones, root, dofs)
    names = {**CMU_BONES, **(joint_map or {})}
    missing = sorted(k for k in KEYPOINTS if names.get(k) not in starts)
    if missing:
        raise AsfAmcFormatError(f"{asf}: no bone for {missing[0]} (looked for {names.get(missing[0])!r}); name it "
                                f"with a joint map, e.g. `{missing[0]}: BoneName`")
    positions = {k: starts[names[k]] @ (Y_UP_TO_Z_UP.T if up_axis == "y" else np.eye(3)) for k in KEYPOINTS}
    return SourceMotion(name=path.stem, positions=positions, times=np.arange(len(root)) / fps,
                        source=f"ASF/AMC {asf.name} {path.name}", license="see the license of the source dataset")
