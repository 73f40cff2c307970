"""`fbcpr motions ...`: import motion files into clips, list a clip folder, render a clip to video."""
from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import typer
from rich.table import Table

from fbcpr.cli.common import HelpGroup, cli_errors, console, err_console, progress
from fbcpr.core.errors import InputError

if TYPE_CHECKING:
    from motions.clip import Clip
    from motions.retarget import RetargetReport

motions_app = typer.Typer(help="Motion clips: import (AMASS, DeepMimic, BVH, ASF/AMC), inspect, render.",
                          no_args_is_help=True,
                          cls=HelpGroup)


#: the suffixes of motion files (AMASS, DeepMimic, BVH, ASF/AMC); a folder's other files are no motions
MOTION_SUFFIXES = (".npz", ".txt", ".json", ".bvh", ".amc", ".asf")


def _expand(sources: list[Path]) -> tuple[list[Path], list[Path]]:
    """(files, skipped): files as given; folders expand to the files inside them with a motion file's suffix
    (recursively, sorted), and their other files (a README, an index) are skipped rather than failed."""
    out: list[Path] = []
    skipped: list[Path] = []
    for src in sources:
        if not src.is_dir():
            out.append(src)
            continue
        for p in sorted(src.rglob("*")):
            if p.is_file() and not p.name.startswith("."):
                (out if p.suffix.lower() in MOTION_SUFFIXES else skipped).append(p)
    return out, skipped


def _write_json_atomic(data: dict, path: Path) -> None:
    from fbcpr.core.checkpoint import umask_permissions

    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        json.dump(data, fh, indent=2)
    umask_permissions(tmp)
    os.replace(tmp, path)


def read_joint_map(path: Path) -> dict[str, str]:
    """A --joint-map file: YAML `keypoint: JointName` lines."""
    import yaml

    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise InputError(f"--joint-map: cannot read {path} ({err.strerror})") from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        raise InputError(f"--joint-map: {where}: invalid YAML: {err.problem}") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise InputError(f"--joint-map: {path} must map keypoint names to joint names (e.g. `l_toe: toe1-1.L`)")
    return data


def _clipped_text(entry: dict) -> str:
    """`12: L_Knee_y 8, R_Elbow_x 4, ...`: the total, then the joints that were clipped to their range most."""
    joints = entry["clipped_joints"]
    if not joints:
        return "0"
    named = ", ".join(f"{j} {n}" for j, n in list(joints.items())[:3])
    return f"{entry['clipped_joint_frames']}: {named}{', ...' if len(joints) > 3 else ''}"


def summary_entry(path: Path, clip_file: str, clip: Clip, report: RetargetReport) -> dict:
    """One imported take's line in import_summary.json: its size and its quality, with the flags worth a look."""
    joint_frames = max(clip.n_frames * (clip.qpos.shape[1] - 7), 1)
    return {"file": str(path), "clip": clip_file, "frames": clip.n_frames, "seconds": round(clip.seconds, 3),
            "clipped_joint_frames": report.clipped_total,
            "clipped_joints": dict(sorted(report.clipped.items(), key=lambda kv: -kv[1])),
            "max_foot_penetration_m": round(report.max_penetration, 4),
            "max_contact_gap_m": round(report.max_contact_gap, 4), "foot_slide_m_s": round(report.foot_slide, 4),
            "contact_share": round(report.contact_share, 3),
            "at_limit_share": round(sum(report.at_limits.values()) / joint_frames, 4),
            "at_limit_joints": dict(list(report.at_limits.items())[:5]),
            "peak_limb_speed_legs_s": round(report.peak_limb_speed, 1),
            "keypoint_error_m": round(report.keypoint_error, 4), "flags": report.flags()}


def merge_summary(path: Path, clips: list[dict], failures: list[dict]) -> dict:
    """import_summary.json of a folder after one more import: a clip written now replaces its earlier entry, a file
    that imports now drops its earlier failure, everything else is kept."""
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        old = {}
    old = old if isinstance(old, dict) else {}
    by_clip = {c["clip"]: c for c in old.get("clips", []) if isinstance(c, dict) and "clip" in c}
    by_clip.update({c["clip"]: c for c in clips})
    imported = {c["file"] for c in clips}
    by_file = {f["file"]: f for f in old.get("failures", []) if isinstance(f, dict) and f.get("file") not in imported}
    by_file.update({f["file"]: f for f in failures})
    merged = list(by_clip.values())
    return {"clips": merged, "failures": list(by_file.values()),
            "total_seconds": round(sum(c.get("seconds", 0.0) for c in merged), 3)}


@motions_app.command("import")
@cli_errors
def import_cmd(
    sources: list[Path] = typer.Argument(..., help="Motion files or folders (AMASS .npz, DeepMimic JSON, BVH, "
                                         "ASF/AMC .amc with its .asf)."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the clip .npz files (created if missing)."),
    up_axis: str = typer.Option(None, "--up-axis", help="Override the source up axis: y or z (AMASS: z, BVH: y)."),
    loop_seconds: float = typer.Option(0.0, "--loop-seconds", help="Repeat cyclic clips until they last this long."),
    no_cache: bool = typer.Option(False, "--no-cache", help="Ignore the conversion cache (~/.cache/fbcpr)."),
    joint_map: Path | None = typer.Option(None, "--joint-map", help="BVH or ASF/AMC: YAML mapping of keypoints to "
                                             "this rig's joint (or bone) names (l_hip, l_knee, l_ankle, l_toe, neck, "
                                             "head, l_shoulder, l_elbow, l_wrist and r_ ones), for rigs not known "
                                             "here."),
    skeleton: Path | None = typer.Option(None, "--skeleton", help="ASF/AMC: the ASF skeleton of the .amc motions "
                                         "(default: <subject>.asf beside each, or the folder's only .asf)."),
    fps: float | None = typer.Option(None, "--fps", help="The sources' frame rate, where a file's own is wrong "
                                     "(a BVH header, AMASS mocap_framerate; AMC files assume 120): the clips last "
                                     "(file's rate / FPS) times as long."),
) -> None:
    """Convert motion files to 30 Hz clips; a failing file is reported and skipped, and writes are atomic.
    Each clip's quality (foot slide, floor penetration, joints clipped or held at a bound, capture glitches) is
    printed and kept in import_summary.json beside the clips, with the reasons it is worth a look under "flags"."""
    from fbcpr.core.paths import check_output_folder
    from motions.clip import save_clip
    from motions.importers import import_file

    check_output_folder(out, "--out", [("the source", src) for src in sources])
    if up_axis not in (None, "y", "z"):
        raise typer.BadParameter("--up-axis must be y or z")
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise typer.BadParameter(f"--fps must be a positive number of frames per second, got {fps}")
    names = read_joint_map(joint_map) if joint_map is not None else None
    files, skipped = _expand(sources)
    if skipped:
        err_console.print(f"skipped {len(skipped)} file{'s' if len(skipped) > 1 else ''} in the folders that hold no "
                          f"motion: {', '.join(p.name for p in skipped[:5])}{', ...' if len(skipped) > 5 else ''}",
                          highlight=False)
    skeletons = [p for p in files if p.suffix.lower() == ".asf"]  # read with their motions, not as motions
    files = [p for p in files if p.suffix.lower() != ".asf"]
    if not files:
        raise InputError("SOURCES: no input files found")
    out.mkdir(parents=True, exist_ok=True)
    done: list[dict] = []
    failed: list[dict] = []
    used: set[str] = set()
    with progress() as bar:
        task = bar.add_task("importing", total=len(files))
        for path in files:
            bar.update(task, description=f"importing {path.name}")
            try:
                clip, report = import_file(path, up_axis=up_axis, loop_seconds=loop_seconds, use_cache=not no_cache,
                                           joint_map=names, skeleton=skeleton, fps=fps)
                stem = clip.name
                k = 1
                while stem in used:  # two sources with one name in a single run keep both
                    k += 1
                    stem = f"{clip.name}_{k}"
                used.add(stem)
                save_clip(clip, out / f"{stem}.npz")
                done.append(summary_entry(path, f"{stem}.npz", clip, report))
            except Exception as err:  # one bad file must not stop the others
                failed.append({"file": str(path),
                               "reason": str(err).strip().splitlines()[0] if str(err) else type(err).__name__})
            bar.advance(task)
    seconds = sum(d["seconds"] for d in done)
    _write_json_atomic(merge_summary(out / "import_summary.json", done, failed), out / "import_summary.json")
    flagged = sum(bool(d["flags"]) for d in done)
    table = Table(title=f"Imported {len(done)} clip(s), {seconds:.1f} s of motion -> {out}",
                  caption=f"{flagged} clip(s) flagged" if flagged else None)
    for col in ("clip", "frames", "seconds", "clipped joint-frames", "penetration (m)", "foot slide (m/s)",
                "contact", "limbs (legs/s)", "flags"):
        table.add_column(col, justify="left" if col in ("clip", "clipped joint-frames", "flags") else "right")
    for d in done:
        table.add_row(d["clip"], str(d["frames"]), f"{d['seconds']:.1f}", _clipped_text(d),
                      f"{d['max_foot_penetration_m']:.3f}", f"{d['foot_slide_m_s']:.3f}", f"{d['contact_share']:.0%}",
                      f"{d['peak_limb_speed_legs_s']:.0f}", ", ".join(d["flags"]) or "-")
    if done:  # an empty table before the errors says nothing
        console.print(table)
    if skeletons:
        console.print(f"skeletons read with their motions, not imported: {', '.join(p.name for p in skeletons)}")
    for f in failed:
        err_console.print(f"[red]failed[/] {f['file']}: {f['reason']}", highlight=False)
    if failed:
        err_console.print(f"{len(failed)} file(s) failed; see {out / 'import_summary.json'}")
        raise typer.Exit(1)


@motions_app.command("synthetic")
@cli_errors
def synthetic_cmd(
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the clip .npz files (created if missing)."),
    prefix: str = typer.Option("synthetic_", "--prefix", help="Put before each clip's name and file name, so the "
                               "clips sit beside imported ones without a clash (DeepMimic has a 'walk' too)."),
) -> None:
    """Write the built-in clips (stand, tpose, arm_raise, squat, walk, turn) into a folder, e.g. beside imported
    clips, so that a training run's demonstrations and MoCap init also hold standing states."""
    from dataclasses import replace

    from fbcpr.core.paths import check_output_folder
    from motions.clip import save_clip
    from motions.synthetic import default_clips

    check_output_folder(out, "--out")
    if not re.fullmatch(r"[A-Za-z0-9_-]*", prefix):
        raise typer.BadParameter("--prefix may only hold letters, digits, '_' and '-'")
    clips = [replace(c, name=f"{prefix}{c.name}") for c in default_clips()]
    clashes = [c.name for c in clips if (out / f"{c.name}.npz").exists()]
    if clashes:
        raise InputError(f"--out: {out}: {', '.join(clashes)}.npz already exist; give another --prefix or --out")
    for clip in clips:
        save_clip(clip, out / f"{clip.name}.npz")
    console.print(f"wrote {len(clips)} clips ({sum(c.seconds for c in clips):.1f} s) to {out}: "
                  + ", ".join(c.name for c in clips), highlight=False)


@motions_app.command("info")
@cli_errors
def info_cmd(folder: Path = typer.Argument(..., help="Folder of clip .npz files.")) -> None:
    """Table of the clips in a folder (unreadable files are listed with the reason)."""
    from motions.clip import ClipFormatError, load_clip

    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder")
    paths = sorted(folder.glob("*.npz"))
    if not paths:
        raise InputError(f"no .npz clips in {folder}")
    table = Table(title=str(folder))
    for col in ("clip", "frames", "seconds", "pelvis z (m)", "source", "license"):
        table.add_column(col, justify="right" if col in ("frames", "seconds", "pelvis z (m)") else "left")
    total, count = 0.0, 0
    for p in paths:
        try:
            c = load_clip(p)
        except ClipFormatError as err:
            table.add_row(p.name, "-", "-", "-", f"[red]invalid: {err}[/]", "")
            continue
        total += c.seconds
        count += 1
        z = c.qpos[:, 2]
        table.add_row(c.name, str(c.n_frames), f"{c.seconds:.1f}", f"{z.min():.2f}-{z.max():.2f}", c.source, c.license)
    table.caption = f"{count} clip(s), {total:.1f} s"
    console.print(table)


@motions_app.command("render")
@cli_errors
def render_cmd(
    clip_path: Path = typer.Argument(..., help="A clip .npz file."),
    out: Path = typer.Argument(..., help="Output video (out.mp4) or, for a .png name, a strip of still frames."),
    width: int = typer.Option(640, help="Frame width in pixels (a multiple of 16 avoids resizing)."),
    height: int = typer.Option(480, help="Frame height in pixels."),
    stills: int = typer.Option(6, help="Number of evenly spaced frames in a .png strip."),
) -> None:
    """Play a clip back kinematically (no physics) from the tracking camera; write a video or a .png strip."""
    from humanoid_env.model import load_model  # first: it picks a headless GL backend before mujoco loads
    from humanoid_env.render import TrackRenderer, write_video
    from motions.clip import load_clip

    clip = load_clip(clip_path)
    strip = out.suffix.lower() == ".png"
    rows = np.linspace(0, clip.n_frames - 1, stills).round().astype(int) if strip else np.arange(clip.n_frames)
    renderer = TrackRenderer(load_model(), height=height, width=width)
    frames = []
    try:
        with progress() as bar:
            task = bar.add_task(f"rendering {clip.name}", total=len(rows))
            for q in clip.qpos[rows]:
                frames.append(renderer.render_qpos(q[None])[0])
                bar.advance(task)
    finally:
        renderer.close()
    if strip:
        import imageio.v2 as imageio

        out.parent.mkdir(parents=True, exist_ok=True)
        imageio.imwrite(out, np.concatenate(frames, axis=1))
        times = ", ".join(f"{r / clip.fps:.1f}" for r in rows)
        console.print(f"wrote {out} ({len(rows)} frames of {clip.name} at t = {times} s)")
        return
    write_video(frames, out, fps=clip.fps)
    console.print(f"wrote {out} ({clip.n_frames} frames, {clip.seconds:.1f} s)")


def register(app: typer.Typer) -> None:
    app.add_typer(motions_app, name="motions")
