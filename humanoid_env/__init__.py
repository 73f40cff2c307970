"""MuJoCo SMPL humanoid: model, observation function, Gymnasium environments and tasks."""
import os
import sys

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") and "mujoco" not in sys.modules:
    os.environ.setdefault("MUJOCO_GL", "egl")  # headless default; MuJoCo reads it once, at its first import

import gymnasium

from humanoid_env.model import BODY_NAMES, JOINT_NAMES, NQ, NU, NV, load_model, model_path
from humanoid_env.observation import LAYOUT, OBS_DIM, POSE, observe

ENV_ID = "fbcpr/SMPLHumanoid-v0"
if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point="humanoid_env.env:HumanoidEnv")

__all__ = [
    "BODY_NAMES", "JOINT_NAMES", "NQ", "NU", "NV", "LAYOUT", "OBS_DIM", "POSE", "ENV_ID", "load_model", "model_path",
    "observe",
]
