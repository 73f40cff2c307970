"""Motion library: loading, deterministic split, window and state sampling, EMD-based priorities."""
from __future__ import annotations

import numpy as np
import pytest

from humanoid_env.model import default_qpos
from motions.clip import from_qpos, save_clip
from motions.library import MotionLibrary, emd_bins, priorities_from_emd


def _clip(name: str, n: int, speed: float, tag: float = 0.0):
    q = np.repeat(default_qpos()[None], n, axis=0)
    q[:, 0] = speed * np.arange(n) / 30.0  # distinct root x per frame identifies the source frame
    q[:, 1] = tag  # identifies the clip in states
    q[:, 7 + 40] = 0.01 * np.arange(n) + 0.1 * tag  # a shoulder angle makes every observation distinct
    return from_qpos(q, name=name, source="test", license="MIT")


@pytest.fixture(scope="module")
def lib():
    return MotionLibrary([_clip("a", 20, 1.0, 1), _clip("b", 9, 2.0, 2), _clip("c", 40, 3.0, 3), _clip("d", 5, 4.0, 4)])


def test_priority_formula_matches_the_paper():
    emd = np.array([0.1, 0.7, 0.99, 1.0, 2.2, 4.9, 5.0, 9.0])
    # clip to [0.5, 5], bins of width 0.5 starting at 0.5; EMD >= 5 gets the tenth bin
    np.testing.assert_array_equal(emd_bins(emd), [0, 0, 0, 1, 3, 8, 9, 9])
    np.testing.assert_allclose(priorities_from_emd(emd), [1 / 3, 1 / 3, 1 / 3, 1, 1, 1, 1 / 2, 1 / 2])
    assert emd_bins(np.linspace(0, 10, 1001)).max() == 9  # exactly 10 bins


def test_priorities_drive_sampling(lib):
    lib.set_priorities_from_emd({"a": 0.6, "b": 0.7, "c": 0.8, "d": 4.0})  # a,b,c share a bin; d alone
    np.testing.assert_allclose(lib.priorities, [1 / 3, 1 / 3, 1 / 3, 1.0])
    qpos, _ = lib.sample_states(np.random.default_rng(0), 20000)
    share_d = np.mean(qpos[:, 1] == 4)
    assert abs(share_d - 0.5) < 0.02  # half of the mass goes to the lone hard motion
    with pytest.raises(ValueError, match="unknown names \\['zz'\\]"):
        lib.set_priorities_from_emd({"a": 1, "b": 1, "c": 1, "d": 1, "zz": 1})
    with pytest.raises(ValueError, match="missing names \\['d'\\]"):
        lib.set_priorities_from_emd({"a": 1, "b": 1, "c": 1})
    lib.priorities = np.ones(len(lib))


def test_windows_are_consecutive_observations_of_one_clip(lib):
    rng = np.random.default_rng(1)
    w = lib.sample_windows(rng, 64, 8)
    assert w.shape == (64, 8, 358) and w.dtype == np.float32
    flat = lib._obs
    for window in w:
        start = np.flatnonzero(np.all(flat == window[0], axis=1))
        assert any(np.array_equal(flat[s:s + 8], window) for s in start)
    # clip d (5 frames) can never host an 8-frame window; clip c can host 33 starts
    w_long = lib.sample_windows(rng, 200, 30)
    np.testing.assert_allclose(w_long[:, :, 214], 3.0, atol=1e-4)  # root x velocity of clip c only
    with pytest.raises(ValueError, match="no clip has 41 frames"):
        lib.sample_windows(rng, 1, 41)


def test_windows_name_their_clip_and_patterns_pick_clips_by_name(lib):
    w, clip = lib.sample_window_clips(np.random.default_rng(3), 100, 4)
    assert clip.shape == (100,) and set(clip) == {0, 1, 2, 3}
    speeds = np.array([1.0, 2.0, 3.0, 4.0])        # each clip's root x velocity (observation column 214)
    np.testing.assert_allclose(w[:, :, 214], np.repeat(speeds[clip][:, None], 4, 1), atol=1e-4)
    np.testing.assert_array_equal(lib.sample_window_clips(np.random.default_rng(3), 100, 4)[0], w)
    np.testing.assert_array_equal(lib.sample_windows(np.random.default_rng(3), 100, 4), w)   # the same draw
    np.testing.assert_array_equal(lib.matching(["a", "[cd]"]), [True, False, True, True])
    assert not lib.matching(["A", "x*"]).any()      # case-sensitive, whole names


def test_sample_states_returns_clip_frames(lib):
    qpos, qvel = lib.sample_states(np.random.default_rng(2), 50)
    assert qpos.shape == (50, 76) and qvel.shape == (50, 75)
    all_q = np.concatenate([c.qpos for c in lib.clips])
    assert all(np.any(np.all(all_q == q, axis=1)) for q in qpos)


def test_split_is_deterministic_and_disjoint():
    clips = [_clip(f"m{i:02d}", 3, 1.0) for i in range(40)]
    train, test = MotionLibrary(clips).split(0.25)
    train2, test2 = MotionLibrary(clips[::-1]).split(0.25)
    assert sorted(test.names) == sorted(test2.names) and sorted(train.names) == sorted(train2.names)
    assert not set(train.names) & set(test.names) and len(train) + len(test) == 40
    assert 3 <= len(test) <= 18


def test_load_folder_and_errors(tmp_path):
    for c in (_clip("x", 4, 1.0), _clip("y", 6, 1.0)):
        save_clip(c, tmp_path / f"{c.name}.npz")
    lib = MotionLibrary.load(tmp_path)
    assert lib.names == ["x", "y"] and lib.total_seconds == pytest.approx(10 / 30)
    assert MotionLibrary.load([tmp_path / "y.npz"]).names == ["y"]
    with pytest.raises(ValueError, match="duplicate clip names \\['x'\\]"):
        MotionLibrary([lib.clips[0], lib.clips[0]])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no .npz clips"):
        MotionLibrary.load(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="not a folder"):
        MotionLibrary.load(tmp_path / "nope")


def test_env_motions_takes_one_clip_file_for_single_demonstration_imitation(tmp_path):
    from fbcpr.core.schema import EnvConfig
    from fbcpr.envs.bundle import make_env

    for c in (_clip("x", 40, 1.0), _clip("y", 60, 1.0)):
        save_clip(c, tmp_path / f"{c.name}.npz")
    one = make_env(EnvConfig(name="humanoid", motions=str(tmp_path / "y.npz")), 2, 0)
    assert one.library.names == ["y"]
    assert make_env(EnvConfig(name="humanoid", motions=str(tmp_path)), 2, 0).library.names == ["x", "y"]


def test_focus_clips_start_their_share_of_episodes_on_the_named_clips(tmp_path):
    from fbcpr.core.errors import ConfigError
    from fbcpr.core.schema import EnvConfig
    from fbcpr.envs.bundle import make_env

    for c in (_clip("x", 40, 1.0, tag=1), _clip("y", 60, 1.0, tag=2)):
        save_clip(c, tmp_path / f"{c.name}.npz")
    rng = np.random.default_rng(0)
    cfg = EnvConfig(name="humanoid", motions=str(tmp_path), fall_prob=0.0, stand_prob=0.0, focus_prob=1.0,
                    focus_clips=["y"])
    qpos, _ = make_env(cfg, 2, 0).env.init.sample(rng, 200)
    assert np.all(qpos[:, 1] == 2)  # every start is a frame of y (tag 2), none of x
    assert len(np.unique(qpos[:, 0])) > 30  # frames spread along the clip
    cfg.focus_prob, cfg.stand_prob = 0.25, 0.25
    qpos, _ = make_env(cfg, 2, 0).env.init.sample(rng, 800)
    # MoCap starts (0.5) split evenly between x and y (equal priorities); the focus share (0.25) goes to y alone
    assert 0.18 < (qpos[:, 1] == 1).mean() < 0.32
    assert 0.42 < (qpos[:, 1] == 2).mean() < 0.58
    cfg.focus_clips = ["y", "z"]
    with pytest.raises(ConfigError, match="env.focus_clips: 'z' is not a clip of env.motions"):
        make_env(cfg, 2, 0)


def test_focus_motions_start_their_share_of_episodes_on_clips_outside_the_library(tmp_path):
    from fbcpr.core.config import config_from_dict, load_config
    from fbcpr.core.errors import ConfigError
    from fbcpr.core.schema import EnvConfig
    from fbcpr.envs.bundle import make_env
    from motions.demonstrations import Demonstration, save_demonstration

    (tmp_path / "lib").mkdir()
    (tmp_path / "demos").mkdir()
    save_clip(_clip("x", 40, 1.0, tag=1), tmp_path / "lib" / "x.npz")
    demo = _clip("d", 30, 1.0, tag=3)
    save_demonstration(Demonstration(demo, np.zeros((29, 69), np.float32), "rest"), tmp_path / "demos" / "d.npz")
    cfg = EnvConfig(name="humanoid", motions=str(tmp_path / "lib"), fall_prob=0.0, stand_prob=0.0, focus_prob=0.5,
                    focus_motions=str(tmp_path / "demos"))
    rng = np.random.default_rng(0)
    qpos, _ = make_env(cfg, 2, 0).env.init.sample(rng, 800)
    assert 0.42 < (qpos[:, 1] == 3).mean() < 0.58  # the demonstration's frames (its actions file is no clip)
    assert np.all(np.isin(qpos[:, 1], (1, 3)))
    assert make_env(cfg, 2, 0).library.names == ["x"]  # the library, its reward and tracking are unchanged
    cfg.focus_motions = str(tmp_path / "nothing")
    with pytest.raises(ConfigError, match="env.focus_motions: .*nothing does not exist"):
        make_env(cfg, 2, 0)
    with pytest.raises(ConfigError, match="env.focus_motions: .*not both"):
        config_from_dict({"env": {"focus_prob": 0.5, "focus_clips": ["x"], "focus_motions": str(tmp_path)}})
    with pytest.raises(ConfigError, match="env.focus_motions: give focus clips"):
        config_from_dict({"env": {"focus_motions": str(tmp_path)}})
    (tmp_path / "run.yaml").write_text("env:\n  motions: lib\n  focus_prob: 0.5\n  focus_motions: demos\n")
    assert load_config(tmp_path / "run.yaml").env.focus_motions == str(tmp_path / "demos")  # from the file's folder
