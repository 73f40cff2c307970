"""lab/gpu/pack.py: a run's newest checkpoint -> at most N parts under the size cap -> a loadable model."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.conftest import humanoid_states
from fbcpr import BFM
from fbcpr.core.checkpoint import save_checkpoint
from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr.model import FBCPRModel

spec = importlib.util.spec_from_file_location("pack", Path(__file__).parents[1] / "gpu" / "pack.py")
pack = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pack)


@pytest.fixture
def run_dir(tmp_path):
    """A run dir whose latest checkpoint has a tiny humanoid model and 3000 reward states."""
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69}})
    buf = humanoid_states(3000, seed=0)
    root = tmp_path / "run" / "checkpoints"
    save_checkpoint(root / "step_0000000100", FBCPRModel(cfg.model), cfg, reward_buffer=buf)
    (root / "latest").write_text("step_0000000100")
    return tmp_path / "run"


def test_pack_fits_the_caps_and_unpacks_to_a_loadable_model(run_dir, tmp_path, monkeypatch):
    monkeypatch.setattr(pack, "PART_BYTES", 100_000)
    original = BFM.load(run_dir)
    half_bytes = sum(p.numel() * 2 for p in original.model.parameters())
    other_bytes = sum(b.numel() * b.element_size() for b in original.model.buffers())
    monkeypatch.setattr(pack, "TOTAL_BYTES", half_bytes + other_bytes + pack.SLACK_BYTES + 500_000)
    written = pack.pack(run_dir, tmp_path / "out", 50)
    assert 1 < len(written) and all(p.stat().st_size <= 100_000 for p in written)
    assert sum(p.stat().st_size for p in written) <= pack.TOTAL_BYTES
    path = pack.unpack(tmp_path / "out", tmp_path / "here")
    bfm = BFM.load(path)
    kept = len(bfm.reward_buffer["next_obs"])
    assert 1000 < kept < 3000  # trimmed to fit (302 bytes a float16 state without its observation), not dropped
    drawn = original.reward_samples(kept, seed=0)[0]  # the rows pack drew
    for k in ("qpos", "qvel"):
        np.testing.assert_allclose(bfm.reward_buffer[k], drawn[k], rtol=2**-10, atol=1e-6)
    np.testing.assert_allclose(bfm.reward_buffer["next_obs"], drawn["next_obs"], atol=0.02)  # rebuilt from the states
    for (name, got), want in zip(bfm.model.state_dict().items(), original.model.state_dict().values()):
        assert got.dtype == want.dtype  # an ordinary float32 checkpoint again
        torch.testing.assert_close(got, want, rtol=2**-11, atol=1e-7, msg=name)  # float16 rounding at most
    assert bfm.act(np.zeros(358, np.float32), bfm.prompt.reward("move-ego-0-0")).shape == (69,)
    # a later pack replaces the parts; a set with a part missing is refused instead of read truncated
    assert pack.pack(run_dir, tmp_path / "out", 50) == written
    written[1].unlink()
    with pytest.raises(SystemExit, match=r"misses part\(s\) \[1\]"):
        pack.unpack(tmp_path / "out", tmp_path / "again")


def test_pack_refuses_a_model_larger_than_the_parts(run_dir, tmp_path, monkeypatch):
    monkeypatch.setattr(pack, "PART_BYTES", 10_000)
    with pytest.raises(SystemExit, match="does not fit"):
        pack.pack(run_dir, tmp_path / "out", 2)
