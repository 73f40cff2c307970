"""VIRL's video input: small grey frames in [0, 1], rendered from states or read from a folder.

- The point mass is rasterised (a soft dot on a dark arena, batched torch), so the toy can imitate "video".
- Humanoid frames come from the tracking camera (`humanoid_env.render.TrackRenderer`, plain: no shadows,
  reflections, skybox or multisampling), in grey; a 64x64 frame costs a few ms on a software-GL CPU
  (docs/benchmarks.md), so training renders each collected transition once and keeps the frame in the replay buffer.
- A folder of image files (or .npy frames), sorted by name, is a demonstration video.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".npy")
DOT_SIGMA = 0.08  # the toy dot's radius (arena units: the arena is [-1, 1]^2, a demo step 0.04)


class FramesError(ValueError):
    """A demonstration video that cannot be read (missing folder, no frames, mixed sizes)."""


def rasterize_points(pos: Tensor, size: int) -> Tensor:
    """(..., 2) point-mass positions -> (..., size, size) grey frames in [0, 1]: a Gaussian dot, y up."""
    centres = (torch.arange(size, device=pos.device, dtype=pos.dtype) + 0.5) * (2.0 / size) - 1.0
    dx = pos[..., 0, None] - centres                                       # (..., size) along x (columns)
    dy = pos[..., 1, None] - centres.flip(0)                               # rows top to bottom: y decreasing
    return torch.exp(-(dy[..., :, None] ** 2 + dx[..., None, :] ** 2) / (2 * DOT_SIGMA ** 2))


def to_grey(frames: np.ndarray, size: int) -> np.ndarray:
    """(T, H, W[, C]) uint8 or float frames -> (T, size, size) float32 grey in [0, 1] (area resampling)."""
    x = np.asarray(frames, dtype=np.float32)
    if x.ndim == 4:
        x = x[..., :3].mean(-1)
    if x.ndim != 3:
        raise FramesError(f"frames must be (T, H, W) or (T, H, W, C), got shape {x.shape}")
    if x.max(initial=0.0) > 1.0:
        x = x / 255.0
    t = torch.from_numpy(np.ascontiguousarray(x))[:, None]
    return F.interpolate(t, size=(size, size), mode="area")[:, 0].clamp(0, 1).numpy()


def load_frames(folder: str | Path, size: int) -> np.ndarray:
    """A demonstration video from a folder of frame files (sorted by name) as (T, size, size) grey in [0, 1]."""
    import imageio.v3 as iio

    path = Path(folder).expanduser()
    if not path.is_dir():
        raise FramesError(f"{path}: not a folder of frames")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if len(files) < 2:
        raise FramesError(f"{path}: needs at least 2 frame files ({', '.join(IMAGE_SUFFIXES)}), found {len(files)}")
    frames = [np.load(p) if p.suffix.lower() == ".npy" else iio.imread(p) for p in files]
    shapes = {f.shape for f in frames}
    if len(shapes) != 1:
        raise FramesError(f"{path}: frames differ in shape ({sorted(shapes)[:2]})")
    return to_grey(np.stack(frames), size)


def save_frames(frames: np.ndarray, folder: str | Path) -> Path:
    """Write (T, H, W) grey frames in [0, 1] as numbered PNGs (a demonstration video `load_frames` reads)."""
    import imageio.v3 as iio

    path = Path(folder)
    path.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(np.asarray(frames)):
        iio.imwrite(path / f"{i:05d}.png", (np.clip(f, 0, 1) * 255).round().astype(np.uint8))
    return path


class HumanoidFrames:
    """Grey uint8 frames (size x size) of humanoid poses from the tracking camera, one MuJoCo scene each (needs an
    OpenGL backend). `plain` (the default) leaves out shadows, reflections, skybox and multisampling: a 64x64 frame
    then costs a few ms on a software-GL CPU instead of ~0.1 s (docs/benchmarks.md), cheap enough to render every
    collected transition once."""

    def __init__(self, size: int, plain: bool = True) -> None:
        from humanoid_env.model import load_model
        from humanoid_env.render import TrackRenderer

        self.renderer = TrackRenderer(load_model(), size, size, plain=plain)

    def render(self, qpos: np.ndarray) -> np.ndarray:
        """Poses (N, nq) -> (N, size, size) uint8 grey frames (mean of R, G, B)."""
        return self.renderer.render_qpos(qpos).mean(-1).round().astype(np.uint8)

    def close(self) -> None:
        self.renderer.close()


def render_clip(qpos: np.ndarray, size: int, plain: bool = True) -> np.ndarray:
    """Humanoid poses (T, nq) -> (T, size, size) grey frames in [0, 1] from the tracking camera (`HumanoidFrames`)."""
    frames = HumanoidFrames(size, plain)
    try:
        return frames.render(qpos).astype(np.float32) / 255.0
    finally:
        frames.close()
