"""A folder of clips as one small file that travels to a GPU machine, and back into clips there.

A clip stores qvel and obs beside qpos, and obs is most of its bytes (the 202 clips of the tracking training set: 151
MB). Both follow from qpos (`motions.clip.from_qpos` derives them), so the pack keeps qpos alone, in float32, with
each clip's name and provenance: 17 MB for that set. Unpacking derives qvel and obs again; they agree with the
imported clip's to about 1e-5.

    python lab/gpu/clip_pack.py pack data/clips/tracking-train data/clips/tracking-train.pack.npz
    python lab/gpu/clip_pack.py unpack data/clips/tracking-train.pack.npz data/clips/tracking-train
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from motions.clip import FPS, from_qpos, load_clip, save_clip

#: a pack's arrays: every clip's frames end to end, and per clip its length and provenance
KEYS = ("qpos", "lengths", "files", "names", "sources", "licenses")


def pack(folder: Path, out: Path) -> int:
    """Write every clip of `folder` into `out`; returns the number of clips."""
    files = sorted(folder.glob("*.npz"))
    if not files:
        raise SystemExit(f"{folder}: no clips (.npz) to pack")
    clips = [load_clip(f) for f in files]
    off_rate = [c.name for c in clips if c.fps != FPS]
    if off_rate:
        raise SystemExit(f"{folder}: clips not at {FPS} fps cannot be rebuilt from qpos: {', '.join(off_rate)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, qpos=np.concatenate([c.qpos for c in clips]).astype(np.float32),
                        lengths=np.array([c.n_frames for c in clips]), files=np.array([f.stem for f in files]),
                        names=np.array([c.name for c in clips]),
                        sources=np.array([c.source for c in clips]), licenses=np.array([c.license for c in clips]))
    return len(clips)


def unpack(pack_file: Path, folder: Path) -> int:
    """Rebuild the packed clips into `folder` (qvel and obs derived from qpos); returns the number of clips."""
    with np.load(pack_file) as data:
        missing = [k for k in KEYS if k not in data.files]
        if missing:
            raise SystemExit(f"{pack_file}: not a clip pack (no {', '.join(missing)})")
        arrays = {k: data[k] for k in KEYS}
    ends = np.cumsum(arrays["lengths"])
    if len(ends) == 0 or ends[-1] != len(arrays["qpos"]):
        raise SystemExit(f"{pack_file}: the clip lengths do not add up to the {len(arrays['qpos'])} packed frames")
    rows = zip(np.split(arrays["qpos"], ends[:-1]), arrays["files"], arrays["names"], arrays["sources"],
               arrays["licenses"])
    for qpos, stem, name, source, lic in rows:
        save_clip(from_qpos(qpos, name=str(name), source=str(source), license=str(lic)), folder / f"{stem}.npz")
    return len(ends)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("action", choices=("pack", "unpack"))
    ap.add_argument("source", type=Path)
    ap.add_argument("dest", type=Path)
    args = ap.parse_args(argv)
    n = (pack if args.action == "pack" else unpack)(args.source, args.dest)
    print(f"{args.action}ed {n} clips: {args.source} -> {args.dest}")


if __name__ == "__main__":
    main(sys.argv[1:])
