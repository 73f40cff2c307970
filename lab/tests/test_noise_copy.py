"""lab/experiments/noise_copy.py: the same policy to within tiny actor noise, with the same prompts."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fbcpr import BFM

SCRIPT = Path(__file__).parents[1] / "experiments" / "noise_copy.py"
spec = importlib.util.spec_from_file_location("noise_copy", SCRIPT)
noise_copy = importlib.util.module_from_spec(spec)
spec.loader.exec_module(noise_copy)


def test_the_copy_acts_within_the_noise_and_prompts_as_its_model(tmp_path):
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "copy"), "--sigma", "1e-5",
                          "--seed", "3", "--reward-samples", "2000"], capture_output=True, text=True, check=True)
    assert "actions changed by" in out.stdout
    base, copy = BFM.pretrained(), BFM.load(tmp_path / "copy")
    obs = np.random.default_rng(0).standard_normal((128, base.obs_dim)).astype(np.float32)
    z = base.project_z(np.random.default_rng(1).standard_normal((128, base.z_dim)))
    moved = float(((copy.act(obs, z) - base.act(obs, z)) ** 2).mean())
    assert 0.0 < moved < 1e-6                     # the same policy, to far below the exploration noise (2.5e-3)
    assert len(copy.reward_buffer["qpos"]) == 2000
    np.testing.assert_array_equal(copy.backward(obs), base.backward(obs))   # B untouched: the same prompts
    again = noise_copy.noise_copy(BFM.pretrained(), 1e-5, 3)
    assert np.array_equal(again.act(obs, z), copy.act(obs, z))            # seeded


def test_a_bad_sigma_is_refused():
    with pytest.raises(SystemExit, match="--sigma"):
        noise_copy.noise_copy(BFM.pretrained(), float("nan"), 0)
