"""The training path needs only numpy, torch, mujoco, gymnasium, safetensors, yaml, typer and rich (the GPU lease
image of lab/gpu): dm_control, POT, mink, tensorboard and matplotlib are never required by it."""
import json
import subprocess
import sys

import numpy as np
import pytest

from fbcpr import metrics

# Runs in a fresh interpreter with the packages the GPU image lacks made unimportable, recording every attempt;
# trains twice through a priority refresh: without scipy (no EMD solver at all), then with it (assignment EMD).
SCRIPT = r"""
import importlib.abc, json, sys, warnings
blocked = set(sys.argv[2].split(","))
attempts = []

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            attempts.append(name.split(".")[0])
            raise ModuleNotFoundError(f"No module named {name!r} (blocked by the test)", name=name)
        return None

sys.meta_path.insert(0, Block())
import fbcpr.cli.app  # the `fbcpr train` entry point and every command module it registers
from fbcpr.core.config import config_from_dict
from fbcpr.train.trainer import Trainer

cfg = config_from_dict({
    "model": {"preset": "tiny"}, "agent": {"batch_size": 8},
    "env": {"name": "humanoid", "motions": sys.argv[3], "max_episode_steps": 5},
    "train": {"num_envs": 2, "total_env_steps": 16, "warmup_steps": 4, "rollout_steps": 4, "updates_per_rollout": 1,
              "buffer_capacity": 100, "priority_every": 8, "priority_max_clips": 2, "checkpoint_every": 0,
              "log_every": 4, "reward_buffer_size": 8, "torch_threads": 1},
})
out = {}
for run in ("no_scipy", "scipy"):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        Trainer(cfg, f"{sys.argv[1]}/{run}", progress=False).run()
    out[run] = [str(w.message) for w in caught]
    blocked.discard("scipy")
# The shipped model, which a lease continues (--init-from pretrained), and a shipped config that names evaluation
# tasks, whose check on loading must not need dm_control either.
from fbcpr.inference.bfm import resolve_checkpoint
from fbcpr.core.checkpoint import load_checkpoint
from fbcpr.core.config import find_config, load_config
out["pretrained_z_dim"] = load_checkpoint(resolve_checkpoint("pretrained"), "cpu").config.model.z_dim
out["config_eval_tasks"] = load_config(find_config("cpu")).train.eval_tasks
out["attempts"] = sorted(set(attempts))
print(json.dumps(out))
"""
NEVER = ("dm_control", "mink", "matplotlib")  # must not even be attempted on the training path
OPTIONAL = ("ot", "tensorboard")             # tried lazily; a missing one degrades, it does not fail the run


def metric_keys(run_dir):
    return {line.split(",")[0] for line in (run_dir / "metrics.csv").read_text().splitlines()[1:]}


def test_training_path_needs_no_dm_control_pot_mink_tensorboard_scipy(tmp_path, two_clips):
    blocked = ",".join(NEVER + OPTIONAL + ("scipy",))
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path), blocked, str(two_clips)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not set(out["attempts"]) & set(NEVER), out["attempts"]
    assert {"ot", "tensorboard", "scipy"} <= set(out["attempts"])  # the blocker really was in the way
    assert out["pretrained_z_dim"] > 0                     # the shipped model loads, without dm_control
    assert "move-ego-0-2" in out["config_eval_tasks"]      # the reward tasks were checked, without dm_control
    for run in ("no_scipy", "scipy"):
        assert sum("tensorboard is not installed" in w for w in out[run]) == 1, out[run]
        assert (tmp_path / run / "checkpoints" / "latest").exists()
    # no EMD solver: the run goes on, says so, and logs no tracking metrics
    assert any("priority refresh skipped" in w for w in out["no_scipy"]), out["no_scipy"]
    assert "fb_loss" in metric_keys(tmp_path / "no_scipy")
    assert "eval/tracking_emd" not in metric_keys(tmp_path / "no_scipy")
    # scipy but no POT: tracking EMD by the assignment fallback, priorities refreshed
    assert not any("skipped" in w for w in out["scipy"]), out["scipy"]
    assert {"eval/tracking_emd", "eval/tracking_success", "fb_loss"} <= metric_keys(tmp_path / "scipy")


def transport_lp(a, r):
    """EMD by its definition: the transport linear program between two uniform clouds (scipy's HiGHS)."""
    from scipy.optimize import linprog
    from scipy.spatial.distance import cdist

    n, m = len(a), len(r)
    rows = np.kron(np.eye(n), np.ones(m))
    cols = np.kron(np.ones(n), np.eye(m))
    res = linprog(cdist(a, r).ravel(), A_eq=np.vstack([rows, cols]),
                  b_eq=np.concatenate([np.full(n, 1 / n), np.full(m, 1 / m)]), bounds=(0, None))
    return res.fun


def test_emd_without_pot_is_the_exact_transport_cost(monkeypatch):
    monkeypatch.setitem(sys.modules, "ot", None)  # `import ot` now fails, as where POT is not installed
    rng = np.random.default_rng(0)
    for n in (1, 5, 12):
        a, r = rng.normal(size=(n, 214)), rng.normal(size=(n, 214)) + 0.3
        assert metrics.emd(a, r) == pytest.approx(transport_lp(a, r), rel=1e-7)
    with pytest.raises(metrics.EMDUnavailable, match="unequal length"):
        metrics.emd(np.zeros((3, 214)), np.zeros((4, 214)))
