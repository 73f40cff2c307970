"""The sampling planner: its predictions are the env's physics, what it returns is what the env does, and its cost
ranks standing above falling."""
from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mujoco import rollout

from humanoid_env.env import HumanoidEnv
from humanoid_env.errors import EnvError
from humanoid_env.model import N_SUBSTEPS, NQ, NU, NV, default_qpos
from planner import PlannerConfig, TrackingPlanner, sensing_model, up_axis


def standing_reference(frames: int = 3) -> np.ndarray:
    return np.repeat(default_qpos()[None], frames, 0)


def test_up_axis_of_upright_and_upside_down_bodies():
    identity = np.array([1.0, 0.0, 0.0, 0.0])
    flipped = np.array([0.0, 1.0, 0.0, 0.0])  # 180 degrees about x
    quarter = np.array([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])  # 90 degrees about y: z -> x
    np.testing.assert_allclose(up_axis(np.stack([identity, flipped, quarter])),
                               [[0, 0, 1], [0, 0, -1], [1, 0, 0]], atol=1e-12)


def test_sensing_model_predicts_the_envs_physics():
    env = HumanoidEnv()
    env.reset(seed=3)
    model = sensing_model()
    state = np.empty(mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(env.model, env.data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, size=(5, NU))
    ctrl = np.repeat(env.action_map.to_ctrl(actions)[None], N_SUBSTEPS, axis=1)
    predicted, sensed = rollout.rollout(model, [mujoco.MjData(model)], state[None], ctrl,
                                        initial_warmstart=env.data.qacc_warmstart[None].copy())
    for t, a in enumerate(actions):
        env.step(a)
        np.testing.assert_allclose(predicted[0, (t + 1) * N_SUBSTEPS - 1, 1:1 + NQ], env.data.qpos, atol=1e-6)
    # sensors are read at the start of a physics step, so the last row sees the state one step (2.2 ms) before
    env.data.qpos[:] = predicted[0, -2, 1:1 + NQ]
    mujoco.mj_kinematics(env.model, env.data)
    mujoco.mj_comPos(env.model, env.data)
    np.testing.assert_allclose(sensed[0, -1, :3], env.data.subtree_com[1], atol=1e-6)


def test_what_the_planner_returns_is_what_the_env_does():
    planner = TrackingPlanner(standing_reference(), PlannerConfig(samples=4, horizon=4, execute=2, knot_every=2))
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.5  # a shove forward
    motion = planner.run(q0, v0, steps=7)
    assert motion.actions.shape == (7, NU) and motion.qpos.shape == (8, NQ) and motion.obs.shape[0] == 8
    assert len(motion.plan_costs) == 4 and np.isfinite(motion.plan_costs).all()
    assert np.abs(motion.actions).max() <= 1.0
    env = HumanoidEnv()
    obs, _ = env.reset(options={"qpos": q0, "qvel": v0})
    np.testing.assert_allclose(obs, motion.obs[0])
    for t, a in enumerate(motion.actions):
        obs, _, _, _, info = env.step(a)
        np.testing.assert_allclose(info["qpos"], motion.qpos[t + 1], atol=1e-6)
        np.testing.assert_allclose(obs, motion.obs[t + 1], atol=1e-4)


def test_the_target_follows_the_reference_then_blends_into_the_rest_pose():
    ref = standing_reference(4)
    ref[:, 7:] = np.linspace(0.1, 0.4, 4)[:, None]
    planner = TrackingPlanner(ref, PlannerConfig(samples=2, horizon=2, blend_steps=10))
    target = planner.target(np.array([0.0, 1.5, 3.0, 8.0, 13.0, 40.0]))
    np.testing.assert_allclose(target[:3, 7], [0.1, 0.25, 0.4])
    np.testing.assert_allclose(target[3:, 7], [0.2, 0.0, 0.0])  # half-way blended, then rest (0 for this joint)
    np.testing.assert_allclose(target[:, 2], ref[0, 2])  # the pelvis height target stays the reference's


def test_the_cost_ranks_standing_above_falling():
    planner = TrackingPlanner(standing_reference(), PlannerConfig(samples=2, horizon=3, w_balance=10.0))
    target = planner.target(np.arange(3.0))
    env = HumanoidEnv()
    rows = []
    for height, tilt in [(0.0, False), (-0.7, True)]:  # standing, and lying on its side
        q = default_qpos()
        q[2] += height
        if tilt:
            q[3:7] = [np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0]
        env.reset(options={"qpos": q, "qvel": np.zeros(NV)})
        mujoco.mj_comPos(env.model, env.data)
        sensed = np.concatenate([env.data.subtree_com[1], np.zeros(3)]
                                + [env.data.xpos[env.model.body(n).id] for n in ("L_Ankle", "R_Ankle", "L_Toe", "R_Toe")])
        rows.append((np.repeat(q[None], 3, 0), np.zeros((3, NV)), np.repeat(sensed[None], 3, 0)))
    qpos, qvel, sensed = (np.stack(x) for x in zip(*rows))
    cost = planner.cost(qpos, qvel, sensed, target)
    assert cost[0] < 0.1 < cost[1]
    # a capture point off the feet costs more than one over them, while the target stands
    shoved = sensed.copy()
    shoved[0, :, 3] = 2.0
    assert planner.cost(qpos[:1], qvel[:1], shoved[:1], target)[0] > cost[0] + 1.0


@pytest.mark.parametrize("kwargs, word", [(dict(samples=0), "samples"), (dict(horizon=2, execute=3), "execute"),
                                          (dict(noise=-1.0), "noise"), (dict(threads=0), "threads"),
                                          (dict(chains=0), "chains"), (dict(samples=4, elites=5), "elites"),
                                          (dict(noise_decay=0.0), "noise_decay"),
                                          (dict(warm_start=-0.1), "warm_start")])
def test_bad_planner_settings_are_named(kwargs, word):
    with pytest.raises(EnvError, match=word):
        PlannerConfig(**kwargs)


def test_overrides_are_read_as_their_fields_types_and_bad_ones_are_named():
    cfg = PlannerConfig().with_overrides(["chains=4", "noise_decay=0.5", "warm_start=0"])
    assert (cfg.chains, cfg.noise_decay, cfg.warm_start, cfg.samples) == (4, 0.5, 0.0, PlannerConfig.samples)
    for bad, word in ((["chain=4"], "chain=4"), (["chains"], "name=value"), (["chains=two"], "not a int"),
                      (["noise=nan"], "finite"), (["warm_start=maybe"], "not a float"),
                      (["warm_start=1.5"], "warm_start"), (["elites=99"], "elites")):
        with pytest.raises(EnvError, match=word):
            PlannerConfig().with_overrides(bad)


def label_noise(**kwargs) -> float:
    """Mean squared difference of the labels two planner seeds give the same states (a still policy's)."""
    q0, v0 = default_qpos(), np.zeros(NV)
    v0[0] = 0.4
    labels = [TrackingPlanner(standing_reference(), PlannerConfig(samples=8, horizon=8, knot_every=2, threads=1,
                                                                 seed=seed, **kwargs))
              .run(q0, v0, steps=16, policy=lambda obs: np.zeros(NU)).labels for seed in (0, 1)]
    return float(np.square(labels[0] - labels[1]).mean())


def test_averaged_chains_and_elites_make_steadier_labels_than_one_planners_pick():
    one = label_noise()
    assert label_noise(chains=4) < 0.5 * one                    # four independent walks, averaged
    single = label_noise(warm_start=0.0)
    assert label_noise(warm_start=0.0, iterations=3, elites=4, noise_decay=0.7) < 0.7 * single


def test_bad_references_and_steps_are_named():
    with pytest.raises(EnvError, match="shape"):
        TrackingPlanner(np.zeros((3, NQ - 1)))
    bad = standing_reference()
    bad[1, 9] = np.nan
    with pytest.raises(EnvError, match="NaN"):
        TrackingPlanner(bad)
    planner = TrackingPlanner(standing_reference(), PlannerConfig(samples=2, horizon=2))
    with pytest.raises(EnvError, match="steps"):
        planner.run(default_qpos(), np.zeros(NV), steps=0)
