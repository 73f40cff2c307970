"""Import motion files of any supported format into clips: format autodetection, a conversion cache, one entry point.

Formats: AMASS/SMPL `.npz` (direct joint-angle mapping), DeepMimic JSON, BVH and ASF/AMC (keypoint IK
retargeting).
Conversions are cached by file content hash (plus file name, options and converter version) under $FBCPR_CACHE_DIR or
~/.cache/fbcpr, so re-importing the same files is instant; delete that folder to force a fresh conversion.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from motions.clip import FPS, Clip, ClipFormatError, from_qpos, load_clip, save_clip
from motions.formats import FORMATS, UnknownFormatError, detect_format
from motions.kinematics import repeat_loop
from motions.retarget import Retargeter, RetargetReport

__all__ = ["FORMATS", "UnknownFormatError", "cache_dir", "detect_format", "import_file"]

#: Bump when a converter's output changes, so cached conversions are not reused.
CONVERTER_VERSION = "5"


def cache_dir() -> Path:
    return Path(os.environ.get("FBCPR_CACHE_DIR", Path.home() / ".cache" / "fbcpr")) / "motions"


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _cache_key(path: Path, fmt: str, options: dict) -> str:
    h = hashlib.sha256()
    h.update(f"{CONVERTER_VERSION}|{fmt}|{path.name}|{json.dumps(options, sort_keys=True)}|".encode())
    h.update(_file_digest(path).encode())
    return h.hexdigest()[:32]


def _report_to_json(report: RetargetReport) -> str:
    d = dataclasses.asdict(report)
    d["contacts"] = None if report.contacts is None else report.contacts.astype(int).tolist()
    return json.dumps(d)


def _report_from_json(text: str) -> RetargetReport:
    d = json.loads(text)
    d["contacts"] = None if d["contacts"] is None else np.asarray(d["contacts"], dtype=bool)
    return RetargetReport(**d)


_RETARGETER: Retargeter | None = None


def _retargeter() -> Retargeter:
    global _RETARGETER
    if _RETARGETER is None:
        _RETARGETER = Retargeter()
    return _RETARGETER


def import_file(path: str | os.PathLike, up_axis: str | None = None, loop_seconds: float = 0.0,
                use_cache: bool = True, joint_map: dict[str, str] | None = None,
                skeleton: str | os.PathLike | None = None, fps: float | None = None) -> tuple[Clip, RetargetReport]:
    """Convert one motion file to a 30 Hz clip, with a report (clipped joints, floor contact quality).

    up_axis overrides the format's default (AMASS "z", BVH "y"; DeepMimic is always y up).
    loop_seconds > 0 repeats cyclic clips (DeepMimic "wrap") with accumulated root offset until they last that long.
    joint_map names BVH joints (or ASF bones) for keypoints (`motions.importers.bvh.NAMES`) of a rig whose names
    are unknown. skeleton: the ASF of an AMC motion (default: the one beside it, `asfamc.find_skeleton`).
    fps: the source's frame rate, overriding what the file says (a wrong BVH header, AMASS mocap_framerate,
    DeepMimic frame durations) or assumes (AMC: 120); a clip at twice the rate lasts half as long.
    """
    path = Path(path)
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number of frames per second, got {fps!r}")
    fmt = detect_format(path)
    options: dict = {"up_axis": up_axis, "loop_seconds": loop_seconds}
    if joint_map:
        options["joint_map"] = joint_map
    if fps is not None:
        options["fps"] = fps
    if fmt == "amc":
        from motions.importers.asfamc import AsfAmcFormatError, find_skeleton

        skeleton = Path(skeleton) if skeleton is not None else find_skeleton(path)
        if not skeleton.is_file():
            raise AsfAmcFormatError(f"{skeleton}: no such ASF skeleton file")
        options["skeleton"] = _file_digest(skeleton)  # the motion's meaning changes with its skeleton
    key = _cache_key(path, fmt, options) if use_cache else None
    if key is not None:
        cached = cache_dir() / f"{key}.npz"
        meta = cache_dir() / f"{key}.json"
        if cached.is_file() and meta.is_file():
            try:
                return load_clip(cached), _report_from_json(meta.read_text())
            except (ClipFormatError, ValueError, TypeError, KeyError):
                pass  # a damaged cache entry is simply recomputed
    loop = False
    if fmt == "amass":
        from motions.importers.amass import import_amass

        qpos, report, prov = import_amass(path, fps=FPS, up_axis=up_axis or "z", source_fps=fps)
        name, source, license_ = path.stem, prov["source"], prov["license"]
    else:
        if fmt == "deepmimic":
            from motions.importers.deepmimic import load_deepmimic

            src = load_deepmimic(path)
            if fps is not None:
                src.times = np.arange(len(src.times)) / fps
        elif fmt == "amc":
            from motions.importers.asfamc import AMC_FPS, load_amc

            src = load_amc(path, skeleton, up_axis=up_axis or "y", joint_map=joint_map, fps=fps or AMC_FPS)
        else:
            from motions.importers.bvh import load_bvh

            src = load_bvh(path, up_axis=up_axis or "y", joint_map=joint_map, fps=fps)
        qpos, report = _retargeter().run(src)
        name, source, license_, loop = src.name, src.source, src.license, src.loop
    if loop and loop_seconds > 0 and qpos.shape[0] > 2:
        cycles = int(np.ceil(loop_seconds * FPS / (qpos.shape[0] - 1)))
        qpos = repeat_loop(qpos, max(cycles, 1))
    clip = from_qpos(qpos, name=name, source=source, license=license_, fps=FPS)
    if key is not None:
        save_clip(clip, cache_dir() / f"{key}.npz")
        tmp = cache_dir() / f".{key}.json.tmp"
        tmp.write_text(_report_to_json(report))
        os.replace(tmp, cache_dir() / f"{key}.json")
    return clip, report
