"""Lab tests: the experiment scripts and their helper modules (lab/experiments) import each other by name."""
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
