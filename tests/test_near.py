"""NEAR: DSM training of the energy, the annealing rule, the reward transform, config errors, state, and TD3 on it."""
import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from fbcpr.core.config import config_from_dict, load_config
from fbcpr.core.errors import ConfigError
from fbcpr.rewards.near.annealing import Annealer
from fbcpr.rewards.near.config import NEARConfig
from fbcpr.rewards.near.energy import EnergyNet, dsm_loss, noise_levels
from fbcpr.rewards.near.reward import NEARError, NEARReward
from fbcpr.core.protocols import ImitationReward
from fbcpr.envs import toy as pm
from fbcpr.train.trainer import Trainer

torch.set_num_threads(1)
CONFIGS = Path(__file__).resolve().parents[1] / "fbcpr" / "configs"
TINY = dict(hidden_dim=32, hidden_layers=2, lr=3e-3, ema=0.9, sigma_max=1.0, pretrain_steps=300, dataset_size=2000)


def circle_pairs() -> torch.Tensor:
    demo = torch.as_tensor(pm.demo_paths()["circle-ccw"])
    return torch.stack([demo[:-1], demo[1:]], 1)                                     # (199, 2, 2) of (s, s')


@pytest.fixture(scope="module")
def trained() -> NEARReward:
    near = NEARReward(2, NEARConfig(**TINY), seed=0)
    near.pretrain(circle_pairs())
    return near


def test_noise_ladder_is_geometric_from_sigma_max_to_sigma_min():
    s = noise_levels(20.0, 0.01, 50)
    assert s.shape == (50,) and s[0].item() == pytest.approx(20.0) and s[-1].item() == pytest.approx(0.01)
    ratios = s[1:] / s[:-1]
    torch.testing.assert_close(ratios, torch.full_like(ratios, ratios[0].item()))


def test_dsm_loss_decreases_and_the_energy_is_higher_on_data_than_off_it_at_every_level(trained):
    m = trained.pretrain_stats
    assert m["near/dsm_last"] < 0.8 * m["near/dsm_first"], m
    pairs = circle_pairs()
    s, s_next = pairs[:, 0], pairs[:, 1]
    on = trained.anchored_energy(s, s_next)
    far = trained.anchored_energy(s + 0.6, s_next + 0.6)                             # same motion, off the circle
    still = trained.anchored_energy(s, s)                                            # on the circle, not moving
    for sigma in trained.sigmas:
        assert (on / sigma).mean() > (far / sigma).mean() and (on / sigma).mean() > (still / sigma).mean()
    assert on.mean().abs() < 1e-3                                                    # anchored: 0 on the data


def test_dsm_loss_is_zero_for_the_exact_score_of_a_point_mass_at_the_origin():
    # data = {0}: the noised density at sigma is N(0, sigma^2), whose score -x / sigma^2 is e(x) = -|x|^2 / 2 / sigma
    # in the e(x) / sigma form only for one sigma; check the loss at a single level and its non-zero value elsewhere
    class Exact(EnergyNet):
        def forward(self, x):
            return -0.5 * x.square().sum(-1)

    g = torch.Generator().manual_seed(0)
    exact = Exact(3, 4, 1)
    assert dsm_loss(exact, torch.zeros(512, 3), torch.tensor([1.0]), g).item() < 1e-10
    assert dsm_loss(exact, torch.zeros(512, 3), torch.tensor([2.0]), g).item() > 1.0


def test_annealing_moves_the_level_per_algorithm_1():
    a = Annealer(num_levels=4, threshold=0.2)
    assert a.step(-10.0) == 0.0 and a.reference == -10.0 and a.level == 0        # first phase: the reference
    assert a.step(-9.0) == pytest.approx(0.1) and a.level == 0                     # within alpha: stay
    assert a.step(-7.0) == pytest.approx(0.3) and a.level == 1                     # improved > alpha: sharper level
    assert a.reference is None
    a.step(-7.0)                                                                   # new level's reference
    assert a.step(-9.0) == pytest.approx(-2 / 7) and a.level == 0                  # worse by > alpha: back up
    pos = Annealer(num_levels=3, threshold=0.5, level=2, reference=2.0)
    assert pos.step(4.0) == pytest.approx(1.0) and pos.level == 2                  # e / ref - 1 as written; last level
    low = Annealer(num_levels=3, threshold=0.5, level=0, reference=2.0)
    assert low.step(0.5) == pytest.approx(-0.75) and low.level == 0                # first level: no sigma_0


def test_fit_anneals_once_per_rollout_phase_on_observed_transitions_and_the_tanh_transform(trained):
    near = NEARReward(2, NEARConfig(**TINY, anneal_threshold=0.05), seed=0)
    near.load_state(*trained.state())
    pairs = circle_pairs()
    s, s_next = pairs[:, 0], pairs[:, 1]
    bad, good = s + 0.6, s_next + 0.6
    near.observe(bad, good)
    assert near.fit(pairs, {})["near/level"] == 0                                  # reference phase
    assert near.fit(pairs, {})["near/progress"] == 0.0                             # no new phase: no annealing step
    near.observe(s, s_next)                                                        # the agent now moves like the demo
    assert near.fit(pairs, {})["near/level"] == 1
    e = near.anchored_energy(s, s_next) / near.sigma
    recent = sum(near.phase_energies) / len(near.phase_energies) / near.sigma
    torch.testing.assert_close(near.reward(s, s_next), torch.tanh((e - recent) / 10.0))
    near.cfg.transform = False
    torch.testing.assert_close(near.reward(s, s_next), e)


def test_reward_is_batched_finite_and_rejects_nan_and_unpretrained_use(trained):
    r = trained.reward(torch.zeros(7, 2), torch.full((7, 2), 0.05))
    assert r.shape == (7,) and torch.isfinite(r).all()
    with pytest.raises(NEARError, match="non-finite"):
        trained.reward(torch.tensor([[float("nan"), 0.0]]), torch.zeros(1, 2))
    with pytest.raises(NEARError, match="not trained"):
        NEARReward(2, NEARConfig(**TINY)).reward(torch.zeros(1, 2), torch.zeros(1, 2))
    with pytest.raises(NEARError, match="library"):
        NEARReward(2, NEARConfig(**TINY)).fit(circle_pairs(), {})


def test_state_round_trips_through_safetensors(trained, tmp_path):
    assert isinstance(trained, ImitationReward)
    trained.observe(torch.zeros(3, 2), torch.zeros(3, 2))
    tensors, meta = trained.state()
    save_file({k: v.contiguous() for k, v in tensors.items()}, tmp_path / "near.safetensors")
    (tmp_path / "near.json").write_text(json.dumps(meta))
    other = NEARReward(2, NEARConfig(**TINY), seed=5)
    other.load_state(load_file(tmp_path / "near.safetensors"), json.loads((tmp_path / "near.json").read_text()))
    x, y = torch.rand(9, 2), torch.rand(9, 2)
    torch.testing.assert_close(other.reward(x, y), trained.reward(x, y), rtol=0, atol=0)
    assert other.pretrained and other.annealer.state() == trained.annealer.state()
    assert other.fit(circle_pairs(), {}) == trained.fit(circle_pairs(), {})         # the same pending phase


def test_config_errors_name_the_key():
    base = load_config(CONFIGS / "near-toy.yaml")
    assert base.agent.near.sigma_max == 1.0 and base.agent.reward.imitation == "near"
    with pytest.raises(ConfigError, match=r"agent\.near\.sigma_min"):
        config_from_dict({"algorithm": "td3", "agent": {"reward": {"imitation": "near"},
                                                        "near": {"sigma_min": 2.0, "sigma_max": 1.0}}})
    with pytest.raises(ConfigError, match=r"agent\.near\.num_levels"):
        config_from_dict({"algorithm": "td3", "agent": {"near": {"num_levels": 1}}})
    with pytest.raises(ConfigError, match=r"agent\.near\.noise"):
        config_from_dict({"algorithm": "td3", "agent": {"near": {"noise": 1}}})


def test_td3_on_near_runs_end_to_end_on_the_toy_and_resumes_without_pretraining(tmp_path):
    cfg = load_config(CONFIGS / "near-toy.yaml")
    for k, v in TINY.items():
        setattr(cfg.agent.near, k, v)
    cfg.agent.near.pretrain_steps, cfg.agent.near.transform_history = 30, 10
    tc = cfg.train
    tc.total_env_steps, tc.warmup_steps, tc.rollout_steps, tc.updates_per_rollout = 400, 200, 50, 2
    tr = Trainer(cfg, tmp_path, progress=False)
    out = tr.run()
    near = tr.agent.imitation
    assert near.pretrained and len(near.phase_energies) == 4 and "near/level" in out     # phases at 250..400
    assert all(k in out for k in ("reward", "critic_loss")) and torch.isfinite(torch.tensor(out["reward"]))
    cfg.train.total_env_steps = 400 + cfg.agent.batch_size + tc.rollout_steps   # the resumed buffer starts empty
    resumed = Trainer(cfg, tmp_path, resume=True, progress=False)
    assert resumed.agent.imitation.pretrained
    torch.testing.assert_close(resumed.agent.imitation.ema.net[0].weight, near.ema.net[0].weight, rtol=0, atol=0)
    assert resumed.run()["near/pretrain_s"] == out["near/pretrain_s"]              # restored, not pretrained again
