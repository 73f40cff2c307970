"""The model that ships inside the package: loads by name, fits its size budget, prompts, and drives the demo."""
import json
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open
from typer.testing import CliRunner

from fbcpr import BFM
from fbcpr.inference.bfm import PRETRAINED_DIR
from fbcpr.cli.app import app

torch.set_num_threads(1)
MAX_BYTES = 25_000_000  # "at most 25 MB"


def test_ships_within_budget_with_float16_reward_states_and_a_model_card():
    files = {p.name: p.stat().st_size for p in PRETRAINED_DIR.iterdir()}
    assert {"model.safetensors", "config.yaml", "manifest.json", "reward_buffer.safetensors", "README.md"} <= set(files)
    assert sum(files.values()) <= MAX_BYTES, files
    with safe_open(str(PRETRAINED_DIR / "reward_buffer.safetensors"), framework="pt") as f:
        assert set(f.keys()) == {"qpos", "qvel"}  # states only: loading rebuilds the observations
        assert {f.get_slice(k).get_dtype() for k in f.keys()} == {"F16"}
        assert f.get_slice("qpos").get_shape()[0] >= 40_000
    card = (PRETRAINED_DIR / "README.md").read_text()
    for fact in ("DeepMimic", "env steps", "updates", "CPU", "upright"):
        assert fact in card, fact


def test_loads_by_name_and_prompts():
    bfm = BFM.pretrained()
    assert bfm.action_mapping == "rest" and bfm.obs_dim == 358 and bfm.action_dim == 69
    z = bfm.prompt.reward("move-ego-0-0")
    assert z.shape == (bfm.z_dim,) and np.isclose(np.linalg.norm(z), np.sqrt(bfm.z_dim), rtol=1e-4)
    obs = np.asarray(bfm.reward_buffer["next_obs"][:4])
    action = bfm.act(obs, np.broadcast_to(z, (4, bfm.z_dim)))
    assert action.shape == (4, 69) and np.isfinite(action).all() and np.abs(action).max() <= 1.0
    assert BFM.load("pretrained").z_dim == bfm.z_dim
    default = BFM.load()  # no checkpoint named: the shipped model
    assert np.array_equal(default.act(obs, np.broadcast_to(z, (4, bfm.z_dim))), action)


def test_demo_prompts_the_pretrained_model(tmp_path):
    out = tmp_path / "demo"
    res = CliRunner().invoke(app, ["demo", "--out", str(out), "--episodes", "1", "--eval-steps", "5", "--no-video"])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "demo_summary.json").read_text())
    assert summary["model"] == "pretrained" and summary["training"] is None
    assert set(summary["scores"]) == {"FB-CPR", "zero action", "random action"}
    assert "pretrained model" in summary["verdict"]
    # what it does well, next to the floors: the walk from standing starts, pushes held, tracking the walk clip
    prompts = [(row["prompt"], row["metric"]) for row in summary["scores"]["FB-CPR"]]
    assert prompts == [("reward move-ego-0-2, standing starts", "return"),
                       ("reward move-ego-0-0, pushed starts", "share held"), ("track walk", "EMD")]
    verdict = " ".join(summary["verdict"].split())
    for cannot in ("get up", "jump"):  # said plainly, not shown
        assert cannot in verdict, cannot
    title = (PRETRAINED_DIR / "README.md").read_text().split("\n# ", 1)[1].splitlines()[0]
    for data in ("DeepMimic", "CMU", "synthetic", "planned crouches"):  # the card's data, named alike in the demo
        assert (data in title) == (data in verdict), data
    assert "\n\n\n" not in res.output  # no runs of blank lines


def test_stored_reward_prompts_are_the_ones_its_states_give():
    from humanoid_env.tasks.rewards import TASKS

    bfm = BFM.pretrained()
    stored = bfm.reward_prompts
    assert stored is not None and set(stored.z) == set(TASKS) and stored.states == len(bfm.reward_buffer["qpos"])
    # They were inferred at export from the same 50,000 states in float32, before the kept copy was rounded to
    # float16: the z's the kept states give agree to a cosine of 0.99999 (another draw of states: ~0.95).
    for task in ("move-ego-0-0", "move-ego-0-2", "split-1", "raisearms-m-h", *REFINED):
        from_states = bfm.prompt.reward(task, n=10**6)   # n past the sample: inferred from every state, not stored
        z = bfm.prompt.reward(task, refined=False)
        np.testing.assert_array_equal(z, stored.zero_shot(task))  # the stored zero-shot z is the one answered
        assert z @ from_states / (np.linalg.norm(z) * np.linalg.norm(from_states)) > 0.9999, task


#: the tasks whose shipped prompts were refined by rollouts at export, with the search's generations, population and
#: starts (model card, "Stored reward prompts")
REFINED = {"crouch-0": (5, 16, 8), "move-ego-0-4": (15, 16, 16), "raisearms-h-h": (15, 16, 16),
           "rotate-z-5-0.8": (15, 16, 16), "sitonground": (15, 16, 16)}
#: those whose search started from a given z (export --refine-from: a screened z, a demonstration's, or the
#: previous weights' refined z), not from the zero-shot z
STARTED_FROM = ("crouch-0", "raisearms-h-h", "rotate-z-5-0.8", "sitonground")
#: the search seed of each refined prompt: 3, but hands high and sit, searched again for the last stage's weights
SEARCH_SEED = {"raisearms-h-h": 7604, "sitonground": 7605}


def test_the_shipped_prompts_were_stored_for_todays_formulas():
    """A prompt stored for an older formula would be dropped on load with a warning (sitonground, jump-2 and crouch-0
    were revised)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stored = BFM.pretrained().reward_prompts
    assert len(stored.z) == 54 and stored.revisions == {
        "sitonground": {"sitonground": 1}, "jump-2": {"jump-2": 1}, "crouch-0": {"crouch-0": 1}}


def test_five_shipped_prompts_are_refined_and_keep_their_zero_shot_z():
    bfm = BFM.pretrained()
    stored = bfm.reward_prompts
    assert sorted(stored.refined) == list(REFINED)
    for task in REFINED:
        record, z, z0 = stored.refined[task], bfm.prompt.reward(task), bfm.prompt.reward(task, refined=False)
        np.testing.assert_array_equal(z, stored.z[task])
        start = record.get("start", z0)
        assert ("start" in record) == (task in STARTED_FROM), task
        assert 0.8 < z @ start / bfm.z_dim < 0.99, task  # a nearby z, not the one the search started from
        assert (record["generations"], record["population"], record["starts"]) == REFINED[task], task
        assert (record["steps"], record["seed"]) == (300, SEARCH_SEED.get(task, 3)), task
        # the mean reward per step on its search starts; a given start already does some of the behaviour
        assert record["score"] > record["score0"] + (0.05 if task in STARTED_FROM else 0.3), task
