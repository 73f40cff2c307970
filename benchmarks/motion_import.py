"""Motion import speed: seconds of motion converted per second of compute, next to raw MuJoCo kinematics.

    python benchmarks/motion_import.py            # DeepMimic clips from ../shared, a synthetic AMASS file, a BVH
    python benchmarks/motion_import.py --quick    # fewer clips

The reference is mj_kinematics throughput measured in the same run (frames per second), so numbers from
different machines can be compared through the ratio IK frames/s : mj_kinematics frames/s.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from humanoid_env.model import load_model
from humanoid_env.observation import observe
from motions.importers import import_file

ROOT = Path(__file__).resolve().parents[1]
DEEPMIMIC = ROOT.parent / "shared" / "mocap" / "deepmimic" / "motions"


def kinematics_reference(n: int = 20000) -> float:
    """Frames per second of plain mj_kinematics on random poses of our model."""
    model = load_model()
    data = mujoco.MjData(model)
    qpos = np.repeat(model.qpos0[None], 64, axis=0)
    qpos[:, 7:] += np.random.default_rng(0).normal(0, 0.2, (64, 69))
    start = time.perf_counter()
    for i in range(n):
        data.qpos[:] = qpos[i % 64]
        mujoco.mj_kinematics(model, data)
    return n / (time.perf_counter() - start)


def observe_reference(n: int = 3000) -> float:
    model = load_model()
    qpos = np.repeat(model.qpos0[None], n, axis=0)
    start = time.perf_counter()
    observe(model, qpos, np.zeros((n, model.nv)))
    return n / (time.perf_counter() - start)


def time_import(path: Path) -> tuple[float, float, int, int, float, float]:
    """(motion seconds, compute seconds, frames, clipped joint-frames, max foot penetration, max contact gap)."""
    start = time.perf_counter()
    clip, report = import_file(path, use_cache=False)
    return (clip.seconds, time.perf_counter() - start, clip.n_frames, report.clipped_total, report.max_penetration,
            report.max_contact_gap)


def synthetic_amass(folder: Path, seconds: float = 60.0) -> Path:
    n = int(seconds * 120)
    t = np.arange(n) / 120
    poses = np.zeros((n, 156))
    poses[:, 3 * 4] = 0.5 + 0.4 * np.sin(2 * np.pi * t)  # knees
    poses[:, 3 * 5] = 0.5 + 0.4 * np.cos(2 * np.pi * t)
    poses[:, 0] = np.pi / 2  # upright in a z-up world
    trans = np.stack([0.5 * t, np.zeros(n), np.full(n, 0.9)], axis=1)
    path = folder / "bench_amass.npz"
    np.savez(path, poses=poses, trans=trans, mocap_framerate=np.float64(120))
    return path


def synthetic_bvh(folder: Path) -> Path:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_motions_bvh import _squat_bvh

    text, _ = _squat_bvh(n=600, fps=60.0)  # 10 s
    path = folder / "bench_squat.bvh"
    path.write_text(text)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="only walk, cartwheel and one long walk")
    args = parser.parse_args()
    kin = kinematics_reference()
    obs = observe_reference()
    print(f"reference: mj_kinematics {kin:,.0f} frames/s; observe() {obs:,.0f} frames/s")
    rows = []
    names = ["walk", "cartwheel", "long_walk1"] if args.quick else None
    clips = sorted(DEEPMIMIC.glob("humanoid3d_*.txt"))
    if names:
        clips = [p for p in clips if p.stem.removeprefix("humanoid3d_") in names]
    if not clips:
        print(f"(no DeepMimic clips in {DEEPMIMIC}; skipping them)")
    total_motion = total_compute = 0.0
    total_frames = 0
    for p in clips:
        row = time_import(p)
        total_motion += row[0]
        total_compute += row[1]
        total_frames += row[2]
        rows.append((f"deepmimic/{p.stem.removeprefix('humanoid3d_')}", *row))
    with tempfile.TemporaryDirectory() as tmp:
        for path, label in ((synthetic_amass(Path(tmp)), "amass (synthetic, 120 Hz)"),
                            (synthetic_bvh(Path(tmp)), "bvh (synthetic, 60 Hz)")):
            rows.append((label, *time_import(path)))
    print(f"| {'clip':30s} | motion s | frames | compute s | motion s / s | frames/s | clipped | max pen. (m) "
          "| max contact gap (m) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for label, seconds, compute, frames, clipped, pen, gap in rows:
        print(f"| {label:30s} | {seconds:8.1f} | {frames:6d} | {compute:9.2f} | {seconds / compute:12.1f} | "
              f"{frames / compute:8.0f} | {clipped:7d} | {pen:12.3f} | {gap:19.3f} |")
    if clips:
        rate = total_frames / total_compute
        print(f"all DeepMimic: {total_motion:.1f} s of motion in {total_compute:.1f} s = "
              f"{total_motion / total_compute:.1f} s/s, {rate:.0f} frames/s (mj_kinematics is {kin / rate:.0f}x that)")


if __name__ == "__main__":
    main()
