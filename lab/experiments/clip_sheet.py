"""Imported clips side by side, one row per clip, for comparing two imports of the same take by eye.

    python lab/experiments/clip_sheet.py OLD.npz NEW.npz --labels "converter 4" "converter 5" --seconds 0 1 2 3 \\
        --out sheet.png

Each tile is the clip's pose at that second from the tracking camera, labelled with the row's name and the time.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from PIL import Image, ImageDraw

from humanoid_env.model import load_model
from humanoid_env.render import TrackRenderer
from motions.clip import load_clip

TILE_W, TILE_H = 240, 180


def sheet(paths: list[Path], labels: list[str], seconds: list[float]) -> Image.Image:
    """One row per clip, one tile per requested second (clamped to the clip's last frame)."""
    renderer = TrackRenderer(load_model(), TILE_H, TILE_W)
    out = Image.new("RGB", (TILE_W * len(seconds), TILE_H * len(paths)), "white")
    try:
        for row, (path, label) in enumerate(zip(paths, labels)):
            clip = load_clip(path)
            rows = [min(int(round(s * clip.fps)), clip.n_frames - 1) for s in seconds]
            for col, (t, image) in enumerate(zip(rows, renderer.render_qpos(clip.qpos[rows]))):
                tile = Image.fromarray(image)
                ImageDraw.Draw(tile).text((4, 4), f"{label}  t={t / clip.fps:.1f}s", fill=(0, 0, 0))
                out.paste(tile, (col * TILE_W, row * TILE_H))
    finally:
        renderer.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("clips", nargs="+", type=Path)
    ap.add_argument("--labels", nargs="*", default=None, help="one per clip (default: the file names)")
    ap.add_argument("--seconds", nargs="+", type=float, default=[0.0, 1.0, 2.0, 3.0])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    labels = args.labels or [p.stem for p in args.clips]
    if len(labels) != len(args.clips):
        raise SystemExit(f"--labels: {len(labels)} labels for {len(args.clips)} clips")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet(args.clips, labels, args.seconds).save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
