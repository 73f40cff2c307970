"""Test-session setup. MuJoCo reads MUJOCO_GL once, at its first import, so set the headless backend before any
test module imports mujoco (humanoid_env does the same for users, but test collection order is not fixed)."""
import os
import signal

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler for the test, then whatever was there: a runner started as a background job
    inherits SIGINT ignored, and tests of stop signals check that our handler is swapped back for the default."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)
