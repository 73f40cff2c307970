"""Test-session setup. MuJoCo reads MUJOCO_GL once, at its first import, so set the headless backend before any
test module imports mujoco (humanoid_env does the same for users, but test collection order is not fixed)."""
import os

os.environ.setdefault("MUJOCO_GL", "egl")
