"""MuJoCo SMPL humanoid: model, observation function, Gymnasium environments and tasks."""
from humanoid_env.model import BODY_NAMES, JOINT_NAMES, NQ, NU, NV, load_model, model_path
from humanoid_env.observation import LAYOUT, OBS_DIM, POSE, observe

__all__ = ["BODY_NAMES", "JOINT_NAMES", "NQ", "NU", "NV", "LAYOUT", "OBS_DIM", "POSE", "load_model", "model_path", "observe"]
