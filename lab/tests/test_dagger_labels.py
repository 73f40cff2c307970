"""The planner as DAgger's expert (`TrackingPlanner.run(policy=...)`), labelled demonstrations on disk, and
lab/experiments/dagger_labels.py."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from humanoid_env.env import HumanoidEnv
from humanoid_env.errors import EnvError
from humanoid_env.model import NU, NV, default_qpos
from planner import PlannerConfig, TrackingPlanner
from motions.clip import from_qpos, load_clip, save_clip
from motions.demonstrations import (Demonstration, DemonstrationError, actions_path, load_demonstration,
                                   save_demonstration)
from tests.test_demonstrations import planned  # noqa: F401 (a fixture)

SCRIPT = Path(__file__).parents[1] / "experiments" / "dagger_labels.py"


def test_with_a_policy_the_policy_acts_and_the_planner_labels_every_state():
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.4
    planner = TrackingPlanner(default_qpos()[None], PlannerConfig(samples=3, horizon=4, knot_every=2))
    m = planner.run(q0, v0, steps=5, policy=lambda obs: np.full(NU, 0.3))
    assert m.actions.shape == m.labels.shape == (5, NU)
    np.testing.assert_allclose(m.actions, 0.3)                 # the policy acted ...
    assert np.abs(m.labels - 0.3).max() > 0.05                 # ... and the planner chose otherwise
    assert np.abs(m.labels).max() <= 1.0
    assert len(m.plan_costs) == 5                              # one plan per step: a label at every state
    env = HumanoidEnv(action_mapping=planner.amap.mapping)     # the states are the policy's own motion
    env.reset(options={"qpos": q0, "qvel": v0})
    for a in m.actions:
        info = env.step(a)[4]
    np.testing.assert_allclose(info["qpos"], m.qpos[-1], atol=1e-6)
    own = planner.run(q0, v0, steps=4)                          # without a policy the labels are the actions
    np.testing.assert_array_equal(own.labels, own.actions)
    with pytest.raises(EnvError, match=r"policy action must have shape \(69,\), got \(3,\)"):
        planner.run(q0, v0, steps=2, policy=lambda obs: np.zeros(3))
    with pytest.raises(EnvError, match="NaN or inf"):
        planner.run(q0, v0, steps=2, policy=lambda obs: np.full(NU, np.nan))


def test_a_label_tracks_the_reference_from_the_frame_nearest_the_state_not_from_the_step_count():
    ref = np.repeat(default_qpos()[None], 12, 0)
    ref[:, 2] = np.linspace(0.55, 0.95, 12)                    # a rise: the pelvis goes up ...
    ref[:, 7:] = np.linspace(0.6, 0.0, 12)[:, None] * np.sin(np.arange(NU))  # ... and the joints straighten
    planner = TrackingPlanner(ref, PlannerConfig(samples=3, horizon=4, knot_every=2))
    assert [planner.nearest_frame(q) for q in ref] == list(range(12))
    q0, v0 = ref[7], np.zeros(NV)
    label = planner.run(q0, v0, steps=1, policy=lambda obs: np.zeros(NU)).labels[0]
    np.testing.assert_allclose(label, planner.run(q0, v0, steps=1, start_frame=7).actions[0], atol=1e-6)
    assert np.abs(label - planner.run(q0, v0, steps=1, start_frame=0).actions[0]).max() > 0.01


def test_without_warm_start_a_label_is_one_draw_of_noise_from_the_feed_forward_not_a_random_walk():
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.4
    spread = {}
    for warm in (1.0, 0.0):
        cfg = PlannerConfig(samples=8, horizon=8, knot_every=2, threads=1, warm_start=warm)
        planner = TrackingPlanner(default_qpos()[None], cfg)
        m = planner.run(q0, v0, steps=48, policy=lambda obs: np.zeros(NU))
        feed = planner.amap.from_angles(default_qpos()[None, 7:])[0]
        spread[warm] = np.sqrt(np.square(m.labels[-16:] - feed).mean(1)).mean()
    assert spread[0.0] < 0.15                                  # the knot noise's scale, 0.1
    assert spread[1.0] > 2 * spread[0.0]                      # the kept corrections add up


def test_labels_are_saved_beside_the_actions_and_checked(tmp_path, planned):  # noqa: F811
    labels = np.clip(planned.actions + 0.1, -1, 1)
    save_demonstration(Demonstration(planned.clip, planned.actions, "rest", labels), tmp_path / "d.npz")
    back = load_demonstration(tmp_path / "d.npz")
    np.testing.assert_allclose(back.labels, labels, atol=1e-6)
    save_demonstration(planned, tmp_path / "own.npz")
    assert load_demonstration(tmp_path / "own.npz").labels is None
    with pytest.raises(DemonstrationError, match="labels"):
        save_demonstration(Demonstration(planned.clip, planned.actions, "rest", labels[:-1]), tmp_path / "e.npz")
    bad = labels.copy()
    bad[0, 0] = np.nan
    np.savez(actions_path(tmp_path / "d.npz"), actions=planned.actions, action_mapping=np.array("rest"), labels=bad)
    with pytest.raises(DemonstrationError, match=r"d\.actions\.npz \(labels\): .*NaN"):
        load_demonstration(tmp_path / "d.npz")


def test_the_script_labels_a_policys_rollouts_and_saves_them(tmp_path, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    out = subprocess.run([sys.executable, str(SCRIPT), "zero", "--demos", str(tmp_path / "demos"), "--steps", "3",
                          "--samples", "3", "--threads", "1", "--out", str(tmp_path / "round1")],
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert "| shoved | " in out and "mean policy vs label mse over 1 rollouts" in out
    d = load_demonstration(tmp_path / "round1" / "shoved_round1.npz")
    np.testing.assert_array_equal(d.actions, 0.0)              # the zero policy acted
    assert d.labels.shape == (3, NU) and np.abs(d.labels).max() > 0.0
    np.testing.assert_allclose(d.clip.qpos[0], planned.clip.qpos[0])


def test_the_script_measures_a_labels_noise_between_planner_seeds(tmp_path, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    args = [sys.executable, str(SCRIPT), "zero", "--demos", str(tmp_path / "demos"), "--steps", "6", "--samples", "16",
            "--threads", "1", "--planner", "horizon=4", "knot_every=2", "noise=0.3",
            "w_root_speed=100", "--noise-seeds"]  # the shove costs, so noise can win
    noisy = subprocess.run(args + ["1", "2"], capture_output=True, text=True, timeout=300, check=True).stdout
    row = re.search(r"^\| shoved \| [\d.]+ \| [\d.]+ \| ([\d.]+) / ([\d.]+) / ([\d.]+) \|", noisy, re.M)
    assert row and max(map(float, row.groups())) > 0.0, noisy    # other seeds, other labels
    same = subprocess.run(args + ["0"], capture_output=True, text=True, timeout=300, check=True).stdout
    assert "by thirds: 0.0000 / 0.0000 / 0.0000" in same, same   # the same seed labels the same states alike


def test_with_a_reference_every_start_is_labelled_tracking_that_clip(tmp_path, planned):  # noqa: F811
    save_demonstration(planned, tmp_path / "demos" / "shoved.npz")
    crouch = planned.clip.qpos.copy()
    crouch[:, 7:] += 0.3                                         # a pose the shoved demonstration never takes
    save_clip(from_qpos(crouch, "crouch", source="test", license="CC0"), tmp_path / "crouch.npz")
    subprocess.run([sys.executable, str(SCRIPT), "zero", "--demos", str(tmp_path / "demos"), "--steps", "3",
                    "--samples", "3", "--threads", "1", "--planner", "horizon=4", "knot_every=2",
                    "--reference", str(tmp_path / "crouch.npz"), "--out", str(tmp_path / "r")],
                   capture_output=True, text=True, timeout=300, check=True)
    labels = load_demonstration(tmp_path / "r" / "shoved_r.npz").labels

    def planned_labels(reference: np.ndarray) -> np.ndarray:
        planner = TrackingPlanner(reference, PlannerConfig(samples=3, horizon=4, knot_every=2, threads=1))
        return planner.run(planned.clip.qpos[0], planned.clip.qvel[0], 3, policy=lambda obs: np.zeros(NU)).labels

    np.testing.assert_allclose(labels, planned_labels(load_clip(tmp_path / "crouch.npz").qpos), atol=1e-6)
    assert np.abs(labels - planned_labels(planned.clip.qpos)).max() > 0.1  # not the demonstration's own motion
    bad = subprocess.run([sys.executable, str(SCRIPT), "zero", "--demos", str(tmp_path / "demos"), "--reference",
                          str(tmp_path / "missing.npz")], capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "missing.npz" in bad.stderr
