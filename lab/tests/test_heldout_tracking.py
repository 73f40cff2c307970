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


def test_an_npmp_is_diagnosed_through_its_encoder_and_the_means_summarised(tmp_path):
    from fbcpr.apps.npmp.agent import NPMPAgent
    from fbcpr.apps.npmp.checkpoint import save_npmp
    from fbcpr.apps.npmp.config import npmp_config
    from fbcpr.apps.npmp.model import NPMPModel
    from motions.synthetic import arm_raise

    clip = arm_raise(1.0)  # a clip that moves, so the first-pose floor is above zero
    model = NPMPModel(npmp_config(preset="tiny"), clip.obs.shape[1], 69)  # the humanoid's 69 joint targets
    agent = NPMPAgent(save_npmp(tmp_path / "npmp", model, {"expert": "pretrained", "method": "bc", "steps": 0}))
    row = heldout_tracking.diagnose(agent, clip, seed=0)  # an untrained NPMP: not a BFM, its encoder's z's
    assert row["clip"] == clip.name and row["mpjpe"] > 0 and row["emd"] > 0
    assert np.isclose(row["mpjpe_ratio"], row["mpjpe"] / row["mpjpe_floor"], rtol=0.01)  # rows are rounded
    other = {**row, "mpjpe": 3 * row["mpjpe"], "fell_at_s": 0.5}
    mean = heldout_tracking.summarise([row, other])
    assert mean["clips"] == 2 and mean["falls"] == (row["fell_at_s"] is not None) + 1
    assert np.isclose(mean["mpjpe"], 2 * row["mpjpe"])
    assert np.isclose(mean["mpjpe_ratio"], 2 * row["mpjpe"] / row["mpjpe_floor"])
