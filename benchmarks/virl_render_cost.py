"""What VIRL's video input costs: rendering 64x64 grey humanoid frames vs stepping the env, and the toy's frames.

    python benchmarks/virl_render_cost.py [--frames 30] [--size 64]

Renders poses of the DeepMimic walk clip with the tracking camera (`fbcpr.rewards.virl.frames.render_clip`, one MuJoCo
scene each) twice, with the scene's default effects (shadows, reflections, skybox, multisampling) and plain (the
way training renders), and reports the time per frame of each next to the time per env step of the humanoid
(16 envs, random actions: the reference, measured in the same run) and per frame of the point-mass rasteriser.
Last line: RESULT render_ms=<default> plain_ms=<plain> ratio=<default/plain> env_step_ms=<y> toy_frame_us=<z>.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from fbcpr.rewards.virl.frames import HumanoidFrames, rasterize_points
from motions.library import MotionLibrary

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--size", type=int, default=64)
    args = ap.parse_args()
    torch.set_num_threads(1)
    clip = MotionLibrary.load([ROOT / "data" / "clips" / "deepmimic" / "walk.npz"]).clips[0]
    qpos = np.resize(clip.qpos, (args.frames, clip.qpos.shape[1]))
    times = {}
    for plain in (False, True, False, True):                              # interleaved: load drifts alike on both
        renderer = HumanoidFrames(args.size, plain)
        renderer.render(qpos[:1])                                         # renderer start-up, not counted
        t0 = time.perf_counter()
        frames = renderer.render(qpos)
        times.setdefault(plain, []).append((time.perf_counter() - t0) / args.frames)
        renderer.close()
    render, plain_ms = min(times[False]), min(times[True])

    from humanoid_env.vector import VectorHumanoidEnv

    env = VectorHumanoidEnv(16)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for _ in range(20):
        env.step(rng.uniform(-1, 1, (16, env.single_action_space.shape[0])).astype(np.float32))
    step = (time.perf_counter() - t0) / (20 * 16)
    env.close()

    pos = torch.rand(4096, 2) * 2 - 1
    t0 = time.perf_counter()
    rasterize_points(pos, 32)
    toy = (time.perf_counter() - t0) / len(pos)
    print(f"plain humanoid frames {frames.shape} uint8 in [{frames.min()}, {frames.max()}]")
    print(f"RESULT render_ms={1e3 * render:.1f} plain_ms={1e3 * plain_ms:.1f} ratio={render / plain_ms:.1f} "
          f"env_step_ms={1e3 * step:.2f} toy_frame_us={1e6 * toy:.1f}")


if __name__ == "__main__":
    main()
