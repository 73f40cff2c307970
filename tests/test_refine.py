"""Prompt refinement: the search on the sphere, rollout scores against the evaluation runner, bad settings."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from rich.progress import Progress

from conftest import tiny_humanoid_checkpoint
from fbcpr.inference.bfm import BFM
from fbcpr.eval.runner import reward_suite
from fbcpr.core.errors import PromptError
from fbcpr.inference.refine import Search, cross_entropy, goal_objective, project, refine, reward_objective, rollout_score
from humanoid_env.inits import DefaultInit
from humanoid_env.tasks import goal_obs

torch.set_num_threads(1)
D = 16


@pytest.fixture(scope="module")
def bfm(tmp_path_factory) -> BFM:
    return BFM.load(tiny_humanoid_checkpoint(tmp_path_factory.mktemp("refine"), "tiny", seed=0))


def _target_and_start(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    target = project(rng.standard_normal((1, D)))[0]
    return target, project((0.3 * target + rng.standard_normal(D))[None])[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_search_climbs_towards_the_best_direction(seed):
    target, z0 = _target_and_start(seed)
    res = cross_entropy(lambda zs: zs @ target / D, z0, Search(generations=15, seed=seed))
    before, after = z0 @ target / D, res.z @ target / D
    assert 1.0 - after < 0.5 * (1.0 - before)  # at least half of the gap to the best direction closed
    assert np.isclose(np.linalg.norm(res.z), np.sqrt(D), rtol=1e-5)
    assert res.score == pytest.approx(res.z @ target / D, abs=1e-5)
    assert len(res.history) == 16 and res.history[0]["mean_score"] == pytest.approx(res.score0)


def test_the_result_never_scores_below_the_start():
    """When z0 is the optimum every other mean scores lower, so z0 itself comes back."""
    _, z0 = _target_and_start(3)
    res = cross_entropy(lambda zs: zs @ z0 / D, z0, Search(generations=4))
    np.testing.assert_allclose(res.z, z0, rtol=1e-6)
    assert res.score == res.score0 and res.cosine == pytest.approx(1.0)
    assert res.history[-1]["mean_score"] < res.score


def test_rollout_scores_equal_the_evaluation_runners_returns(bfm):
    """A candidate's score is the runner's mean return over the same starts, divided by the steps."""
    steps, starts = 6, DefaultInit().sample(np.random.default_rng(0), 3)
    zs = project(np.random.default_rng(1).standard_normal((2, bfm.z_dim)))
    scores = rollout_score(bfm, reward_objective("move-ego-0-2"), starts, steps)(zs)
    for z, got in zip(zs, scores):
        agent = type("Fixed", (), {"z_dim": bfm.z_dim, "action_mapping": bfm.action_mapping,
                                   "act": staticmethod(bfm.act), "reward_z": staticmethod(lambda task: z)})()
        with Progress(disable=True) as progress:
            ret = reward_suite(agent, ["move-ego-0-2"], 3, starts, progress, steps=steps, num_threads=1)
        assert got == pytest.approx(ret["move-ego-0-2"]["return_mean"] / steps, rel=1e-6)
    assert scores[0] != scores[1]


def test_refine_counts_its_episodes_and_keeps_the_sphere(bfm):
    starts = DefaultInit().sample(np.random.default_rng(0), 2)
    z0 = bfm.prompt.reward("move-ego-0-0")
    seen = []
    res = refine(bfm, z0, reward_objective("move-ego-0-0"), starts, steps=4,
                 search=Search(generations=2, population=3, elites=1), on_generation=seen.append)
    assert res.episodes == (2 * 3 + 1) * 2 and len(seen) == 3
    assert res.score >= res.score0
    assert np.isclose(np.linalg.norm(res.z), np.sqrt(bfm.z_dim), rtol=1e-5)


def test_the_goal_objective_is_one_at_the_pose_and_falls_with_distance():
    goal = goal_obs("t_pose")
    far = goal_obs("crouch_low")
    objective = goal_objective(goal)
    values = objective(np.stack([goal, far]), None, None)
    assert values[0] == pytest.approx(1.0) and 0.0 < values[1] < 0.37


@pytest.mark.parametrize("search, match", [
    (Search(elites=17), "elites"),
    (Search(population=1, elites=1), "population"),
    (Search(generations=0), "generations"),
    (Search(sigma=float("nan")), "sigma"),
    (Search(decay=0.0), "decay"),
])
def test_bad_settings_are_named(bfm, search, match):
    with pytest.raises(PromptError, match=match):
        refine(bfm, bfm.prompt.goal("t_pose"), goal_objective(goal_obs("t_pose")),
               DefaultInit().sample(np.random.default_rng(0), 1), steps=2, search=search)


def test_bad_inputs_are_named(bfm):
    starts = DefaultInit().sample(np.random.default_rng(0), 2)
    objective = reward_objective("move-ego-0-0")
    with pytest.raises(PromptError, match="z0 must have shape"):
        refine(bfm, np.ones(bfm.z_dim + 1), objective, starts, steps=2)
    with pytest.raises(PromptError, match="starts"):
        refine(bfm, np.ones(bfm.z_dim), objective, (starts[0], starts[1][:1]), steps=2)
    with pytest.raises(PromptError, match="population x starts = 4097 x 2"):
        refine(bfm, np.ones(bfm.z_dim), objective, starts, steps=2, search=Search(population=4097))
    with pytest.raises(PromptError, match="one finite vector"):
        cross_entropy(lambda zs: np.zeros(len(zs)), np.full(D, np.nan))
    with pytest.raises(PromptError, match="finite values"):
        cross_entropy(lambda zs: np.full(len(zs), np.nan), np.ones(D))
    with pytest.raises(PromptError, match="jupm-2"):
        reward_objective("jupm-2")
