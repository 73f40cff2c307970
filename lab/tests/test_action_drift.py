"""lab/experiments/action_drift.py: a continued model's action change per prompt, next to the base's exploration noise."""
import importlib.util
import subprocess
import sys
from pathlib import Path

import torch

from fbcpr import BFM

SCRIPT = Path(__file__).parents[1] / "experiments" / "action_drift.py"
spec = importlib.util.spec_from_file_location("action_drift", SCRIPT)
action_drift = importlib.util.module_from_spec(spec)
spec.loader.exec_module(action_drift)


def perturbed(scale: float) -> BFM:
    """The shipped model with Gaussian noise of `scale` on its actor's weights."""
    model = BFM.pretrained()
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in model.model.actor.parameters():
            p.add_(torch.randn(p.shape, generator=gen) * scale)
    return model


def test_drift_is_zero_for_the_base_and_grows_with_a_change_of_the_actor():
    base = BFM.pretrained()
    res = action_drift.drift(base, [BFM.pretrained(), perturbed(1e-3), perturbed(1e-2)], ["move-ego-0-2"],
                             episodes=1, steps=20, seed=0)["move-ego-0-2"]
    assert res["0"] == 0.0
    assert 0.0 < res["1"] < res["2"]
    std = base.model.cfg.actor_std
    assert 0.5 * std ** 2 < res["noise"] < 1.5 * std ** 2   # clipped Gaussian exploration noise, per component


def test_command_line_prints_the_reference_and_one_row_per_model(tmp_path):
    perturbed(1e-2).save(tmp_path / "moved")
    out = subprocess.run([sys.executable, str(SCRIPT), "pretrained", str(tmp_path / "moved"), "--tasks", "jump-2",
                          "--steps", "10"], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[1].startswith("reference: the base") and out[2].startswith(str(tmp_path / "moved")[-60:])
    assert float(out[2].split()[-1]) > 0
