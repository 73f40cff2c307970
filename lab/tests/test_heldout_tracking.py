"""lab/experiments/heldout_tracking.py: the measures that say how a tracking rollout fails."""
import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).parents[1] / "experiments" / "heldout_tracking.py"
spec = importlib.util.spec_from_file_location("heldout_tracking", SCRIPT)
heldout_tracking = importlib.util.module_from_spec(spec)
spec.loader.exec_module(heldout_tracking)


def moving_obs(steps: int, seed: int) -> np.ndarray:
    """Observations whose 23 body positions wander smoothly (the rest of the observation is zeros)."""
    rng = np.random.default_rng(seed)
    obs = np.zeros((steps, 358), np.float32)
    obs[:, 0] = 0.9
    obs[:, 1:70] = np.cumsum(rng.normal(0, 0.02, (steps, 69)), axis=0)
    return obs


def test_a_delayed_copy_is_found_at_its_delay_with_no_error_left():
    ref = moving_obs(120, 0)
    agent = np.concatenate([np.repeat(ref[:1], 6, axis=0), ref[:-6]])  # the clip, 6 steps late
    lag, err = heldout_tracking.best_lag(agent, ref)
    assert lag == 6 and err < 1e-6
    assert heldout_tracking.mpjpe(agent, ref) > 0.01
    assert heldout_tracking.best_lag(ref, ref) == (0, 0.0)


def test_takes_map_to_their_imported_clips_and_unique_names():
    from tracking_split import clip_file, clip_name

    clips = Path("data/clips/cmu-all")
    assert clip_file("cmu/bvh-daz/salsa/05.bvh", clips) == clips / "bvh-daz/salsa/05.npz"
    assert clip_file("cmu/expmap/test/running/running_1.txt", clips) == clips / "expmap/test/running/running_1.npz"
    assert clip_file("deepmimic/motions/humanoid3d_walk.txt", clips) == clips / "deepmimic/walk.npz"
    assert clip_name("cmu/bvh-daz/salsa/05.bvh") != clip_name("cmu/bvh-daz/indian/05.bvh")
    assert clip_name("cmu/expmap/test/walking_extra/walking_13.txt") == "expmap_test_walking_extra_walking_13"
