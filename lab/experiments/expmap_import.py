"""The exponential-map CMU set (a motion-prediction benchmark's files) -> the package's clips, via its retargeter.

Each line of a file is one 120 fps frame of 117 numbers: the root position (3), then 38 joints' local rotations as
exponential maps (radians, 3 each, the root's first); line 1 is a rest T-pose. The skeleton is the one the set's
public repository defines (chaneyddtt/Convolutional-Sequence-to-Sequence-Model-for-Human-Dynamics,
src/forward_kinematics_cmu.py, `_some_variables`): CMU's ASF bones in hierarchy order, each joint the end of a
bone, offsets in the ASF's own units (the root path is in the same units; the repository's 70x is for its plots).
As there, frames compose in row-vector form: a child's offset turns by its parent's accumulated rotation, and a
joint's rotation is its local exponential map times its parent's. The keypoints are the bone starts the package's
ASF/AMC importer uses (the hip where the femur starts, ...). The set is y up, like CMU's ASF.

    python lab/experiments/expmap_import.py ../shared/mocap/cmu/expmap --out data/clips/cmu-all/expmap
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motions.clip import FPS, from_qpos, save_clip
from motions.importers.bvh import Y_UP_TO_Z_UP, leading_rest_frames
from motions.retarget import Retargeter, RetargetReport, SourceMotion

EXPMAP_FPS = 120.0
N_JOINTS = 38

#: joint -> parent (the repository's 1-based list, less one; the root has none).
PARENTS = np.array([0, 1, 2, 3, 4, 5, 6, 1, 8, 9, 10, 11, 12, 1, 14, 15, 16, 17, 18, 19, 16, 21, 22, 23, 24, 25, 26,
                    24, 28, 16, 30, 31, 32, 33, 34, 35, 33, 37]) - 1

#: Offsets from the parent joint, in the parent's frame (ASF units). Zero rows are bones of no length.
OFFSETS = np.array([
    [0, 0, 0], [0, 0, 0],
    [1.65674, -1.80282, 0.62477], [2.5972, -7.13576, 0], [2.49236, -6.8477, 0], [0.19704, -0.54136, 2.14581],
    [0, 0, 1.11249], [0, 0, 0],
    [-1.6107, -1.80282, 0.62476], [-2.59502, -7.12977, 0], [-2.4678, -6.78024, 0], [-0.23024, -0.63258, 2.13368],
    [0, 0, 1.11569], [0, 0, 0],
    [0.01961, 2.0545, -0.14112], [0.01021, 2.06436, -0.05921], [0, 0, 0], [0.00713, 1.56711, 0.14968],
    [0.03429, 1.56041, -0.10006], [0.01305, 1.6256, -0.05265], [0, 0, 0],
    [3.54205, 0.90436, -0.17364], [4.86513, 0, 0], [3.35554, 0, 0], [0, 0, 0], [0.66117, 0, 0], [0.53306, 0, 0],
    [0, 0, 0], [0.5412, 0, 0.5412], [0, 0, 0],
    [-3.49802, 0.75994, -0.32616], [-5.02649, 0, 0], [-3.36431, 0, 0], [0, 0, 0], [-0.73041, 0, 0],
    [-0.58887, 0, 0], [0, 0, 0], [-0.59786, 0, 0.59786],
])

#: keypoint -> joint (the end of the bone before the keypoint's bone, i.e. that bone's start).
KEYPOINT_JOINTS = {
    "l_hip": 2, "l_knee": 3, "l_ankle": 4, "l_toe": 5, "r_hip": 8, "r_knee": 9, "r_ankle": 10, "r_toe": 11,
    "neck": 16, "head": 18, "l_shoulder": 21, "l_elbow": 22, "l_wrist": 23,
    "r_shoulder": 30, "r_elbow": 31, "r_wrist": 32,
}


def read_expmap(path: Path) -> np.ndarray:
    """(T, 117) frames of one file, the rest pose on line 1 left out."""
    values = np.loadtxt(path, delimiter=",", ndmin=2)
    if values.shape[1] != 3 + 3 * N_JOINTS or len(values) < 3:
        raise ValueError(f"{path}: expected lines of {3 + 3 * N_JOINTS} numbers and at least 3 lines, got "
                         f"{values.shape}")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: holds NaN or inf")
    return values[1:]


def forward_kinematics(frames: np.ndarray) -> np.ndarray:
    """(T, 38, 3) joint positions, y up, ASF units: the repository's row-vector composition, batched over frames.
    The root translation is the first three columns as they stand (x, y, z): the repository's reversed reading
    (z, y, x) walks subject 02's first take sideways, while this order walks it forward, the way its ASF/AMC
    twin (02_01) does."""
    n = len(frames)
    local = Rotation.from_rotvec(frames[:, 3:].reshape(n * N_JOINTS, 3)).as_matrix().reshape(n, N_JOINTS, 3, 3)
    rot = np.empty_like(local)
    pos = np.empty((n, N_JOINTS, 3))
    for j in range(N_JOINTS):
        p = PARENTS[j]
        if p < 0:
            rot[:, j] = local[:, j]
            pos[:, j] = OFFSETS[j] + frames[:, :3]
        else:
            pos[:, j] = np.einsum("i,tij->tj", OFFSETS[j], rot[:, p]) + pos[:, p]
            rot[:, j] = local[:, j] @ rot[:, p]
    return pos


def load_expmap(path: Path, fps: float = EXPMAP_FPS) -> SourceMotion:
    """Keypoints of one file in the package's z-up world, ready for the retargeter."""
    world = forward_kinematics(read_expmap(path)) @ Y_UP_TO_Z_UP.T
    positions = {k: world[:, j] for k, j in KEYPOINT_JOINTS.items()}
    skip = leading_rest_frames(positions, 1.0 / fps)
    positions = {k: v[skip:] for k, v in positions.items()}
    return SourceMotion(name=f"{path.parent.parent.name}_{path.stem}", positions=positions,
                        times=np.arange(len(positions["l_hip"])) / fps, source=f"CMU exponential-map set {path.name}",
                        license="CMU Graphics Lab Motion Capture Database terms (mocap.cs.cmu.edu)")


def report_entry(path: Path, clip_name: str, frames: int, report: RetargetReport) -> dict:
    """One take's quality, in the fields `fbcpr motions import` writes to import_summary.json."""
    return {"file": str(path), "clip": f"{clip_name}.npz", "frames": frames, "seconds": round(frames / FPS, 3),
            "clipped_joint_frames": report.clipped_total,
            "clipped_joints": dict(sorted(report.clipped.items(), key=lambda kv: -kv[1])),
            "max_foot_penetration_m": round(report.max_penetration, 4),
            "max_contact_gap_m": round(report.max_contact_gap, 4), "foot_slide_m_s": round(report.foot_slide, 4),
            "contact_share": round(report.contact_share, 3),
            "peak_limb_speed_legs_s": round(report.peak_limb_speed, 1),
            "keypoint_error_m": round(report.keypoint_error, 4), "flags": report.flags()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sources", type=Path, nargs="+", help="expmap .txt files or folders of them")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    files = [f for s in args.sources for f in (sorted(s.rglob("*.txt")) if s.is_dir() else [s])]
    retargeter = Retargeter()
    entries = []
    for path in files:
        start = time.perf_counter()
        src = load_expmap(path)
        qpos, report = retargeter.run(src)
        rel = path.relative_to(args.sources[0]) if args.sources[0].is_dir() else Path(path.name)
        out = args.out / rel.parent
        out.mkdir(parents=True, exist_ok=True)
        clip = from_qpos(qpos, name=path.stem, source=src.source, license=src.license, fps=FPS)
        save_clip(clip, out / f"{path.stem}.npz")
        entries.append(report_entry(path, str(rel.with_suffix("")), clip.n_frames, report))
        print(f"{rel}: {clip.seconds:.1f} s in {time.perf_counter() - start:.1f} s, "
              f"flags {', '.join(report.flags()) or '-'}", flush=True)
    summary = {"clips": entries, "failures": [], "total_seconds": round(sum(e["seconds"] for e in entries), 3)}
    (args.out / "import_summary.json").write_text(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
