"""Can the actuators produce a clip's motion? Its joint angles played open loop as PD targets, from chosen frames.

    python lab/experiments/clip_playback.py data/clips/mixed/getup_facedown.npz --starts 0 10 20 30 45 60

From each start frame the humanoid is set to the clip's state, then at every control step the next frame's joint
angles become the PD targets (`ActionMap.from_angles`), with no feedback on balance. It prints the highest and
the final pelvis height per start, next to the clip's own pelvis there. Getting up never happens under any
policy here (lab/log.md section 24); this tells a body that cannot rise from a policy that has not learnt to.
"""
from __future__ import annotations

import argparse

import numpy as np

from humanoid_env.env import HumanoidEnv
from motions.clip import Clip, load_clip


def playback(env: HumanoidEnv, clip: Clip, start: int, after: int) -> np.ndarray:
    """Pelvis heights, one per control step, from the clip's frame `start` under its later frames' joint angles as
    PD targets, and then `after` steps holding the last frame's."""
    env.reset(options={"qpos": clip.qpos[start], "qvel": clip.qvel[start]})
    heights = []
    for t in range(start + 1, clip.n_frames + after):
        _, _, terminated, _, info = env.step(env.action_map.from_angles(clip.qpos[min(t, clip.n_frames - 1), 7:]))
        heights.append(info["qpos"][2])
        if terminated:
            break
    return np.asarray(heights)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("clip", help="a clip .npz (fbcpr motions import)")
    ap.add_argument("--starts", type=int, nargs="+", default=[0, 10, 20, 30, 45, 60], help="start frames")
    ap.add_argument("--after", type=int, default=60, help="steps to hold the last frame's targets after the clip ends")
    args = ap.parse_args()
    clip = load_clip(args.clip)
    if any(not 0 <= k < clip.n_frames for k in args.starts):
        ap.error(f"--starts: frames must be in [0, {clip.n_frames - 1}], got {args.starts}")
    env = HumanoidEnv(max_episode_steps=clip.n_frames + args.after)
    print(f"{clip.name}: {clip.n_frames} frames; pelvis height (m) under the clip's joint angles as open-loop targets")
    print(f"{'start frame':>12s} {'clip pelvis':>12s} {'highest':>8s} {'final':>6s}")
    for k in args.starts:
        heights = playback(env, clip, k, args.after)
        print(f"{k:12d} {clip.qpos[k, 2]:12.2f} {heights.max():8.2f} {heights[-1]:6.2f}")


if __name__ == "__main__":
    main()
