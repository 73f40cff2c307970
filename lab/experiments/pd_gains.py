"""How robust standing is to action noise under our PD gains, next to HumEnv-like softer gains.

    python lab/experiments/pd_gains.py [--envs 16] [--seed 0]

The softer gains are HumEnv's per joint group (learning-facts); they are patched into a copy of the MuJoCo
model for this measurement only. Each row prints the median seconds until the pelvis drops below 0.6 m from a
standing start under the `rest` mapping, for the zero action and for clipped Gaussian action noise; our gains
are the reference row of the same run.
"""
from __future__ import annotations

import argparse
from typing import Callable

import mujoco
import numpy as np

import humanoid_env.vector as vector
from fbcpr.eval.upright import seconds_upright
from humanoid_env.model import JOINT_NAMES, load_model

#: (name fragments, kp, kd, force limit) per joint group, HumEnv's values.
HUMENV_GAINS = ((("Torso", "Spine", "Chest"), 240, 4, 360), (("Hip", "Knee"), 180, 2, 360), (("Thorax",), 120, 1.6, 240),
                (("Ankle",), 90, 2, 180), (("Elbow", "Toe"), 72, 0.8, 144), (("Shoulder",), 48, 1.6, 96),
                (("Neck",), 36, 0.8, 72), (("Head",), 24, 0.8, 48), (("Wrist", "Hand"), 12, 0.8, 24))
#: (sigma, AR(1) coefficient rho) of the action noise; rho 0 is i.i.d. per control step.
NOISES = ((0.0, 0.0), (0.05, 0.0), (0.1, 0.0), (0.2, 0.0), (0.1, 0.9))


def humenv_model(leg_damping: float | None = None) -> Callable[[], mujoco.MjModel]:
    """A loader of our model with HumEnv's PD gains (and optionally passive damping on the leg joints)."""
    def load() -> mujoco.MjModel:
        m = load_model()
        for i, name in enumerate(JOINT_NAMES):
            _, kp, kd, force = next(g for g in HUMENV_GAINS if any(k in name for k in g[0]))
            m.actuator_gainprm[i, 0], m.actuator_biasprm[i, 1:3] = kp, (-kp, -kd)
            m.actuator_forcerange[i] = (-force, force)
            if leg_damping is not None and any(k in name for k in ("Hip", "Knee", "Ankle")):
                m.dof_damping[6 + i] = leg_damping
        return m
    return load


def upright_seconds(loader: Callable[[], mujoco.MjModel], sigma: float, rho: float, envs: int, seed: int,
                    steps: int = 300) -> float:
    """Median seconds upright of `envs` standing starts under clip(AR(1) noise) actions."""
    original = vector.load_model
    vector.load_model = loader
    try:
        env = vector.VectorHumanoidEnv(envs, max_episode_steps=steps + 1, action_mapping="rest")
    finally:
        vector.load_model = original
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    action, heights = np.zeros((envs, env.single_action_space.shape[0])), np.empty((steps, envs))
    for t in range(steps):
        action = rho * action + np.sqrt(1 - rho**2) * rng.normal(0.0, sigma, action.shape)
        obs, *_ = env.step(np.clip(action, -1, 1))
        heights[t] = obs[:, 0]
    env.close()
    return float(np.median(seconds_upright(heights)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--envs", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rows = (("ours (reference)", load_model), ("humenv", humenv_model()), ("humenv + leg damping 10", humenv_model(10.0)))
    print(f"{'gains':26s}" + "".join(f"  s={s:.2f},rho={r:.1f}" for s, r in NOISES))
    for label, loader in rows:
        cells = [upright_seconds(loader, s, r, args.envs, args.seed) for s, r in NOISES]
        print(f"{label:26s}" + "".join(f"  {c:14.2f}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
