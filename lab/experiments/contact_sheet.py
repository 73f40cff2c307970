"""A contact sheet: frames of one model under several prompts, one row per prompt, for where a picture says more.

Each row is one rollout from the default standing start (a tracking row starts from the clip's first frame and
shows the clip beside the body, labelled), sampled every `--every` steps; each frame is labelled with its time and
pelvis height.

    python lab/experiments/contact_sheet.py pretrained --prompts reward:move-ego-0-0 reward:move-ego-0-2 goal:t_pose \\
        track:data/clips/deepmimic/walk.npz --out docs/img/pretrained_prompts.png

`z:FILE.npy` rolls out a z saved by `fbcpr prompt ... --save-z` (for instance a refined prompt).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from fbcpr import BFM
from fbcpr.cli.prompt_cmd import rollout
from humanoid_env.model import CONTROL_HZ
from motions.clip import Clip, load_clip

TILE_W, TILE_H = 224, 168


def prompt_zs(bfm: BFM, spec: str, steps: int) -> tuple[np.ndarray, tuple | None, Clip | None]:
    """`reward:NAME`, `goal:NAME`, `track:CLIP.npz` or `z:FILE.npy` -> (z per step, start state or None for the
    default start, the clip shown beside the body for a tracking row).

    Every prompt is resolved before any rollout, so a typo in the last one fails in seconds, not after minutes of
    rendering the others."""
    kind, _, name = spec.partition(":")
    if kind == "track":
        clip = load_clip(name)
        return bfm.prompt.track(clip)[:steps], (clip.qpos[0], clip.qvel[0]), clip
    if kind == "z":
        z = np.load(name, allow_pickle=False)
        if z.shape != (bfm.z_dim,) or not np.all(np.isfinite(z)):
            raise SystemExit(f"--prompts: {name} must hold one finite z of shape ({bfm.z_dim},), got {z.shape}")
        return np.repeat(bfm.project_z(z)[None], steps, 0), None, None
    if kind not in ("reward", "goal"):
        raise SystemExit(f"--prompts: {spec!r} must be reward:NAME, goal:NAME, track:CLIP.npz or z:FILE.npy")
    z = bfm.prompt.reward(name) if kind == "reward" else bfm.prompt.goal(name)
    return np.repeat(z[None], steps, 0), None, None


def contact_sheet(rows: list[tuple[str, Any, bool]], every: int) -> Image.Image:
    """One row per (label, episode with frames, whether each frame is body | reference side by side), a tile every
    `every` steps labelled with its time and pelvis height."""
    images = []
    for label, ep, paired in rows:
        width = 2 * TILE_W if paired else TILE_W
        tiles = []
        for t in range(0, len(ep.frames), every):
            tile = Image.fromarray(ep.frames[t]).resize((width, TILE_H))
            ImageDraw.Draw(tile).text((4, 4), f"{t / CONTROL_HZ:.1f} s  pelvis {ep.obs[t][0]:.2f} m",
                                      fill=(255, 255, 0))
            tiles.append(tile)
        row = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height + 18), (20, 20, 20))
        ImageDraw.Draw(row).text((4, 2), label, fill=(255, 255, 255))
        for i, tile in enumerate(tiles):
            row.paste(tile, (i * tile.width, 18))
        images.append(row)
    sheet = Image.new("RGB", (max(r.width for r in images), sum(r.height for r in images)), (20, 20, 20))
    y = 0
    for row in images:
        sheet.paste(row, (0, y))
        y += row.height
    return sheet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--prompts", nargs="+", required=True)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--every", type=int, default=15)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    bfm = BFM.load(args.checkpoint)
    prompts = {spec: prompt_zs(bfm, spec, args.steps) for spec in args.prompts}
    rows = [(spec, rollout(bfm, zs, start=start, video=True, reference=clip, label=spec), clip is not None)
            for spec, (zs, start, clip) in prompts.items()]
    sheet = contact_sheet(rows, args.every)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out)
    print(f"{args.out}: {len(rows)} prompts, a frame every {args.every} steps")


if __name__ == "__main__":
    main()
