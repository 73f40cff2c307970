"""DeepMimic humanoid3d JSON clips -> keypoints for retargeting.

The DeepMimic character is y up, faces +x with its right side towards +z, and rests with the arms hanging down.
We run its forward kinematics in its own frame, then rotate the world by +90 deg about x (y up -> z up, +z right
-> +y left), which also makes its rest frames of root, chest, neck and feet equal to ours, so those orientations
are handed to the IK. Arms are matched by keypoints only, which is what absorbs the arms-down vs T-pose difference.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motions.limits import check_frame_times, read_text
from motions.retarget import SourceMotion

N_VALUES = 44
LICENSE = "MIT (DeepMimic, Xue Bin Peng et al.; mocap from CMU and SFU databases)"
#: y-up (DeepMimic) to z-up (ours): v_ours = UP @ v_dm.
UP = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])

# Attach offsets of humanoid3d (metres, DeepMimic frame), from its character file.
_CHEST = (0.0, 0.236151, 0.0)
_NECK = (0.0, 0.223894, 0.0)
_HIP = 0.084887
_THIGH = (0.0, -0.421546, 0.0)
_SHIN = (0.0, -0.409870, 0.0)
_SHOULDER = (-0.02405, 0.24350, 0.18311)
_UPPER_ARM = (0.0, -0.274788, 0.0)
_FOREARM = (0.0, -0.258947, 0.0)
_TOE = (0.13, -0.045, 0.0)  # front of the foot box, in the ankle frame
_SOLE = ((-0.043, -0.05, 0.0), (0.133, -0.05, 0.0))  # heel and toe under the foot box, in the ankle frame
_HEAD = (0.0, 0.175, 0.0)  # centre of the head sphere, in the neck frame


class DeepMimicFormatError(ValueError):
    """A DeepMimic file that cannot be read; the message names the file and the problem."""


def _quat(rows: np.ndarray, path: Path, what: str) -> Rotation:
    norms = np.linalg.norm(rows, axis=1)
    if np.any(norms < 1e-6):
        raise DeepMimicFormatError(f"{path}: {what} quaternion has zero length at frame {int(np.argmin(norms))}")
    return Rotation.from_quat(rows / norms[:, None], scalar_first=True)


def read_frames(path: str | Path) -> tuple[np.ndarray, bool]:
    """(T,44) frame rows and the loop flag, validated."""
    path = Path(path)
    text = read_text(path, DeepMimicFormatError)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as err:
        raise DeepMimicFormatError(f"{path}: not a readable DeepMimic JSON file ({err})") from None
    except RecursionError:
        raise DeepMimicFormatError(f"{path}: not a DeepMimic JSON file (nested too deeply)") from None
    except MemoryError:
        raise DeepMimicFormatError(f"{path}: too large to read into memory") from None
    if not isinstance(doc, dict) or "Frames" not in doc:
        raise DeepMimicFormatError(f"{path}: no \"Frames\" list")
    rows = doc["Frames"]
    if not isinstance(rows, list) or len(rows) < 2:
        raise DeepMimicFormatError(f"{path}: \"Frames\" must be a list of at least 2 frames")
    bad = [i for i, r in enumerate(rows) if not isinstance(r, list) or len(r) != N_VALUES]
    if bad:
        raise DeepMimicFormatError(f"{path}: frame {bad[0]} does not have {N_VALUES} numbers")
    try:
        frames = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise DeepMimicFormatError(f"{path}: frames contain non-numeric values") from None
    if not np.all(np.isfinite(frames)):
        raise DeepMimicFormatError(f"{path}: frames contain NaN or inf")
    check_frame_times(frames[:-1, 0], str(path), DeepMimicFormatError)  # the last frame's duration is unused
    loop = doc.get("Loop", "none")
    if loop not in ("wrap", "none"):
        raise DeepMimicFormatError(f"{path}: \"Loop\" must be \"wrap\" or \"none\", got {loop!r}")
    return frames, loop == "wrap"


def load_deepmimic(path: str | Path) -> SourceMotion:
    """Keypoints and segment orientations of a DeepMimic clip, in our z-up world."""
    path = Path(path)
    f, loop = read_frames(path)
    times = np.concatenate([[0.0], np.cumsum(f[:-1, 0])])
    root_pos = f[:, 1:4]
    r_root = _quat(f[:, 4:8], path, "root")
    r_chest = r_root * _quat(f[:, 8:12], path, "chest")
    r_neck = r_chest * _quat(f[:, 12:16], path, "neck")
    chest = root_pos + r_root.apply(_CHEST)
    neck = chest + r_chest.apply(_NECK)
    pos = {"neck": neck, "head": neck + r_neck.apply(_HEAD)}
    rot = {"pelvis": r_root, "chest": r_chest, "head": r_neck}
    soles = {}
    # side: (letter, hip quat col, knee col, ankle quat col, shoulder quat col, elbow col, +z sign)
    for s, hip_c, knee_c, ankle_c, sh_c, elbow_c, sign in (("r", 16, 20, 21, 25, 29, 1.0),
                                                          ("l", 30, 34, 35, 39, 43, -1.0)):
        r_hip = r_root * _quat(f[:, hip_c:hip_c + 4], path, f"{s} hip")
        r_knee = r_hip * Rotation.from_rotvec(np.outer(f[:, knee_c], [0, 0, 1]))
        r_ankle = r_knee * _quat(f[:, ankle_c:ankle_c + 4], path, f"{s} ankle")
        hip = root_pos + r_root.apply((0.0, 0.0, sign * _HIP))
        knee = hip + r_hip.apply(_THIGH)
        ankle = knee + r_knee.apply(_SHIN)
        r_sh = r_chest * _quat(f[:, sh_c:sh_c + 4], path, f"{s} shoulder")
        r_elbow = r_sh * Rotation.from_rotvec(np.outer(f[:, elbow_c], [0, 0, 1]))
        shoulder = chest + r_chest.apply((_SHOULDER[0], _SHOULDER[1], sign * _SHOULDER[2]))
        elbow = shoulder + r_sh.apply(_UPPER_ARM)
        pos.update({
            f"{s}_hip": hip, f"{s}_knee": knee, f"{s}_ankle": ankle, f"{s}_toe": ankle + r_ankle.apply(_TOE),
            f"{s}_shoulder": shoulder, f"{s}_elbow": elbow, f"{s}_wrist": elbow + r_elbow.apply(_FOREARM),
        })
        rot[f"{s}_foot"] = r_ankle
        soles[s] = np.stack([ankle + r_ankle.apply(p) for p in _SOLE], axis=1) @ UP.T
    up = Rotation.from_matrix(UP)
    return SourceMotion(
        name=path.stem.removeprefix("humanoid3d_"),
        positions={k: v @ UP.T for k, v in pos.items()},
        orientations={k: (up * r * up.inv()).as_quat(scalar_first=True) for k, r in rot.items()},
        times=times, loop=loop, floor=0.0, soles=soles, source=f"DeepMimic {path.name}", license=LICENSE,
    )
