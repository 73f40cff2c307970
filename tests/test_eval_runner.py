"""The benchmark runner end to end on tiny budgets: floor baselines, oracle agents, outputs and the CLI."""
import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from fbcpr.eval.agents import Agent, RandomAgent, ZeroAgent
from fbcpr.inference.agents import make_agent
from fbcpr.eval.runner import evaluate
from humanoid_env.actions import ActionMap
from humanoid_env.model import load_model
from humanoid_env.tasks import goal_obs, goal_qpos
from motions.library import MotionLibrary
from motions.synthetic import stand, tpose

ACTIONS = ActionMap(load_model())


def to_action(qpos: np.ndarray) -> np.ndarray:
    return ACTIONS.from_angles(qpos[..., 7:])


class PoseOracle:
    """Its z is the PD target of a known pose: act() plays z back. Goal and tracking prompts that reach the
    runner intact must therefore make it succeed, while the floor baselines fail."""

    name = "oracle"
    z_dim = 69

    def __init__(self, clips=()):
        self.clips = {c.obs.tobytes(): c for c in clips}

    def act(self, obs, z, mean=True):
        return np.asarray(z, np.float32)

    def reward_z(self, reward):
        return to_action(goal_qpos("a_pose"))

    def goal_z(self, goal):
        match = [n for n in ("a_pose", "t_pose", "arms_stretch") if np.allclose(goal_obs(n), goal)]
        return to_action(goal_qpos(match[0]))

    def track_z(self, obs_seq):
        return to_action(self.clips[np.asarray(obs_seq).tobytes()].qpos[1:])


@pytest.fixture(scope="module")
def library():
    return MotionLibrary([stand(seconds=1.0), tpose(seconds=1.0)])


def test_agents_follow_the_protocol():
    for agent in (RandomAgent(0), ZeroAgent(), PoseOracle()):
        assert isinstance(agent, Agent)
    obs = np.zeros((3, 358), np.float32)
    a = RandomAgent(0).act(obs, np.zeros((3, 0)))
    assert a.shape == (3, 69) and np.all(np.abs(a) <= 1) and a.std() > 0.3
    assert np.all(ZeroAgent().act(obs, np.zeros((3, 0))) == 0)
    assert ZeroAgent().track_z(np.zeros((7, 358))).shape == (7, 0)
    with pytest.raises(ValueError, match="358"):
        ZeroAgent().goal_z(np.zeros(10))


def test_random_agent_end_to_end_with_outputs(tmp_path, library):
    res = evaluate(RandomAgent(0), "all", tasks=["move-ego-0-0", "jump-2", "a_pose", "stand"], episodes=2, steps=12,
                   motions=library, out=tmp_path, show_progress=False)
    assert set(res["reward"]) == {"move-ego-0-0", "jump-2"} and set(res["goal"]) == {"a_pose"}
    assert set(res["tracking"]) == {"stand"}
    for r in res["reward"].values():
        assert 0 <= r["return_mean"] <= 12 and len(r["returns"]) == 2
    assert res["reward"]["move-ego-0-0"]["category"] == "Stand"
    g = res["goal"]["a_pose"]
    assert 0 <= g["proximity"] <= 1 and g["success"] in (0.0, 0.5, 1.0)
    assert res["tracking"]["stand"]["success"] == 0.0 and res["tracking"]["stand"]["emd"] > 0.5
    assert res["tracking"]["stand"]["emd_hold_first_pose"] < res["tracking"]["stand"]["emd"]  # random falls
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["summary"] == json.loads(json.dumps(res["summary"]))
    for png in ("reward_tasks.png", "reward_categories.png", "goal_proximity.png", "goal_success.png",
                "tracking_emd.png"):
        assert (tmp_path / png).stat().st_size > 1000


def test_tracking_reports_the_hold_the_first_pose_floor():
    """A clip that stands still is tracked by holding its first pose (EMD near 0); one that moves is not, and a
    tracker must beat that EMD to track anything the clip does after its first frame."""
    from fbcpr.eval.runner import hold_first_pose_emd
    from motions.synthetic import walk

    still, moving = hold_first_pose_emd(stand(2.0)), hold_first_pose_emd(walk(2.0))
    assert still < 0.1 and moving > 5 * max(still, 0.05)


def test_oracle_beats_floor_baselines(library):
    kw = dict(tasks=["a_pose", "arms_stretch", "stand", "tpose"], episodes=2, steps=45, motions=library,
              fall_prob=0.0, show_progress=False)
    oracle = evaluate(PoseOracle(library.clips), "all", **kw)
    zero = evaluate(ZeroAgent(), "all", **kw)
    for goal in ("a_pose", "arms_stretch"):  # a_pose is near the (stand clip) start: anyone passes by it
        assert oracle["goal"][goal]["success"] == 1.0
        assert oracle["goal"][goal]["proximity"] > zero["goal"][goal]["proximity"] + 0.5
    assert zero["goal"]["arms_stretch"]["success"] == 0.0
    assert oracle["tracking"]["stand"]["success"] == 1.0 and zero["tracking"]["stand"]["success"] == 0.0
    # action 0 holds the rest pose, which is the T-pose clip: only the stand clip separates the two by EMD
    assert oracle["tracking"]["stand"]["emd"] < 0.2 * zero["tracking"]["stand"]["emd"]


def test_same_seed_same_results(library):
    kw = dict(suite="reward", tasks=["move-ego-0-0"], episodes=2, steps=10, show_progress=False, seed=3)
    a = evaluate(RandomAgent(1), **kw)["reward"]["move-ego-0-0"]["returns"]
    b = evaluate(RandomAgent(1), **kw)["reward"]["move-ego-0-0"]["returns"]
    assert a == b


def test_bad_arguments(library):
    with pytest.raises(ValueError, match="suite"):
        evaluate(ZeroAgent(), "dance")
    with pytest.raises(ValueError, match="Known families"):
        evaluate(ZeroAgent(), "reward", tasks=["not-a-task"], show_progress=False)
    with pytest.raises(ValueError, match="motions"):
        evaluate(ZeroAgent(), "tracking")
    with pytest.raises(ValueError, match="'t_pose' is a goal task"):
        evaluate(ZeroAgent(), "reward", tasks=["t_pose"], show_progress=False)
    with pytest.raises(ValueError, match="neither a goal pose, a clip"):
        evaluate(ZeroAgent(), "all", tasks=["stand_still"], motions=library, show_progress=False)
    with pytest.raises(ValueError, match="episodes"):
        evaluate(ZeroAgent(), "reward", episodes=0)


def test_cli_eval_command(tmp_path):
    from fbcpr.cli import eval_cmd

    app = typer.Typer()
    app.callback()(lambda: None)  # a group, as in the real app with several commands
    eval_cmd.register(app)
    runner = CliRunner()
    out = tmp_path / "ev"
    res = runner.invoke(app, ["eval", "zero", "--suite", "reward", "--tasks", "move-ego-0-0,raisearms-l-l",
                              "--episodes", "1", "--steps", "5", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "move-ego-0-0" in res.output and (out / "results.json").exists()
    bad = runner.invoke(app, ["eval", "random", "--tasks", "fly-away", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 1 and "neither a goal pose" in bad.output and "Traceback" not in bad.output
    unused = runner.invoke(app, ["eval", "zero", "--suite", "tracking", "--episodes", "3", "--out", str(tmp_path / "y")])
    assert unused.exit_code == 1 and "--episodes: reward and goal episodes only" in unused.output
    assert make_agent("random").name == "random"


def test_cli_eval_on_a_tiny_checkpoint(tmp_path):
    """A real (untrained, tiny) FB-CPR checkpoint goes through all three suites via BFM.load."""
    import torch

    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.cli import eval_cmd
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 358, "action_dim": 69},
                            "agent": {"seq_length": 4, "batch_size": 8}})
    poses = ("a_pose", "t_pose", "crouch_low", "lie_back") * 4
    buf = {"next_obs": np.stack([goal_obs(g) for g in poses]), "qpos": np.stack([goal_qpos(g) for g in poses]),
           "qvel": np.zeros((16, 75))}
    ckpt = save_checkpoint(tmp_path / "tiny", FBCPRModel(cfg.model), cfg, reward_buffer=buf)
    app = typer.Typer()
    app.callback()(lambda: None)
    eval_cmd.register(app)
    out = tmp_path / "ev"
    res = CliRunner().invoke(app, ["eval", str(ckpt), "--tasks", "move-ego-0-0,t_pose,stand", "--episodes", "1",
                                   "--steps", "4", "--out", str(out)])
    assert res.exit_code == 0, res.output
    saved = json.loads((out / "results.json").read_text())
    assert set(saved) >= {"reward", "goal", "tracking", "summary"}
    assert saved["tracking"]["stand"]["frames"] == 120


def test_upright_measures_separate_holding_still_from_random_actions():
    from fbcpr.eval.upright import upright

    zero, rand = upright(ZeroAgent(), episodes=2, steps=45), upright(RandomAgent(0), episodes=2, steps=45)
    assert zero.median_seconds == pytest.approx(1.5)           # the rest pose holds for the whole 1.5 s
    assert rand.median_seconds < 1.2 and not rand.got_up.any()  # random PD targets fall within about a second


def test_seconds_upright_counts_until_the_first_drop_and_a_given_z_reaches_the_agent():
    from fbcpr.eval.upright import pelvis_heights, seconds_upright
    from humanoid_env.inits import DefaultInit

    h = np.full((60, 3), 0.9)
    h[15:, 0] = 0.3           # falls at step 15 (0.5 s at 30 Hz)
    h[40, 1] = 0.5            # one dip at step 40 counts as the fall
    np.testing.assert_allclose(seconds_upright(h), [0.5, 40 / 30, 2.0])

    class Recorder(ZeroAgent):
        z_dim = 4

        def __init__(self):
            self.seen = []

        def act(self, obs, z):
            self.seen.append(np.array(z))
            return super().act(obs, z)

    agent = Recorder()
    pelvis_heights(agent, DefaultInit(), episodes=2, steps=2, seed=0, prompt=np.arange(4.0))
    assert all(z.shape == (2, 4) and (z == np.arange(4.0)).all() for z in agent.seen)


class Unpromptable(PoseOracle):
    """Cannot be prompted for one reward task (as a checkpoint whose buffer that reward is zero on), and is
    interrupted (Ctrl-C) when asked for `stop_at` goal."""

    def __init__(self, stop_at=None):
        super().__init__()
        self.stop_at = stop_at

    def reward_z(self, reward):
        from fbcpr.core.errors import PromptError

        if reward == "jump-2":
            raise PromptError("reward 'jump-2' is zero on all 1024 buffer samples")
        return super().reward_z(reward)

    def goal_z(self, goal):
        if self.stop_at is not None and np.allclose(goal_obs(self.stop_at), goal):
            raise KeyboardInterrupt
        return super().goal_z(goal)


def test_a_task_that_cannot_be_prompted_is_skipped_and_results_are_written_as_they_come(tmp_path, library):
    from rich.console import Console

    from fbcpr.eval.report import print_report

    out = tmp_path / "ev"
    res = evaluate(Unpromptable(), "all", tasks=["jump-2", "move-ego-0-0", "t_pose"], episodes=1, steps=3,
                   motions=library, out=out, show_progress=False)
    assert list(res["reward"]) == ["move-ego-0-0"] and "t_pose" in res["goal"]
    assert res["skipped"] == {"reward/jump-2": "reward 'jump-2' is zero on all 1024 buffer samples"}
    saved = json.loads((out / "results.json").read_text())
    assert saved["complete"] and saved["skipped"] == res["skipped"]
    con = Console(width=100, record=True)
    print_report(res, con)
    assert "skipped 1 (reward/jump-2): reward 'jump-2' is zero" in con.export_text()
    with pytest.raises(KeyboardInterrupt):
        evaluate(Unpromptable(stop_at="t_pose"), "goal", tasks=["a_pose", "t_pose"], episodes=1, steps=3,
                 motions=library, out=tmp_path / "partial", show_progress=False)
    partial = json.loads((tmp_path / "partial" / "results.json").read_text())
    assert not partial["complete"] and list(partial["goal"]) == ["a_pose"]


def test_eval_says_what_it_will_simulate(library):
    from fbcpr.eval.runner import plan

    chosen = {"reward": ["a", "b"], "goal": ["t_pose"], "tracking": ["stand"]}
    text = plan(chosen, ("reward", "goal", "tracking"), 10, 300, library)
    assert text.startswith("evaluating 2 reward tasks x 10 episodes x 300 steps, 1 goal poses x 10 episodes x 300 "
                           "steps, 1 clips to track: 9,029 env steps, about 1 minute on 2 CPU cores")


def test_the_estimate_is_in_minutes_and_scales_with_the_work():
    """The defaults (every task, 10 episodes of 300 steps) take about 40 minutes on 2 CPU cores; the quick mode
    and one-episode runs far less."""
    from humanoid_env.tasks import GOALS, TASKS
    from motions.synthetic import default_library

    from fbcpr.cli.eval_cmd import QUICK_CLIPS, QUICK_EPISODES, QUICK_STEPS, QUICK_TASKS
    from fbcpr.eval.runner import estimate_seconds, plan

    lib, suites = default_library(), ("reward", "goal", "tracking")
    everything = {"reward": list(TASKS), "goal": list(GOALS), "tracking": list(lib.names)}
    assert 30 * 60 <= estimate_seconds(everything, suites, 10, 300, lib) <= 50 * 60
    assert "about 4" in plan(everything, suites, 10, 300, lib)
    one = estimate_seconds(everything, suites, 1, 60, lib)
    assert 30 <= one <= 150
    quick = {"reward": [t for t in QUICK_TASKS if t in TASKS], "goal": [t for t in QUICK_TASKS if t in GOALS],
             "tracking": list(lib.names[:QUICK_CLIPS])}
    assert estimate_seconds(quick, suites, QUICK_EPISODES, QUICK_STEPS, lib) < 45
    assert "under a minute" in plan(quick, suites, QUICK_EPISODES, QUICK_STEPS, lib)


def test_eval_quick_runs_a_short_list_and_logs_progress_lines(tmp_path, monkeypatch):
    """`fbcpr eval --quick`: its own few tasks and clips, short episodes; in a log (not a terminal) the progress is
    plain lines with the time left, not a bar drawn once at the end."""
    from fbcpr.cli.app import app
    from fbcpr.cli.eval_cmd import QUICK_TASKS

    res = CliRunner().invoke(app, ["eval", "zero", "--quick", "--out", str(tmp_path / "q")])
    assert res.exit_code == 0, res.output
    results = json.loads((tmp_path / "q" / "results.json").read_text())
    assert (results["episodes"], results["steps"]) == (2, 150)
    done = set(results["reward"]) | set(results["goal"]) | set(results["tracking"])
    assert done == {*QUICK_TASKS, "stand", "tpose"}
    assert "under a minute on 2 CPU cores" in " ".join(res.output.split())
    assert "reward: 100% (600/600)" in res.output and "left" in res.output
    assert "━" * 40 not in res.output  # no bar (the report's tables use shorter runs of it)
    both = CliRunner().invoke(app, ["eval", "zero", "--quick", "--tasks", "jump-2", "--out", str(tmp_path / "b")])
    assert both.exit_code != 0 and "--quick or --tasks" in both.output


def test_line_progress_writes_lines_with_the_time_left():
    import io

    from rich.console import Console

    from fbcpr.core.progress import LineProgress, progress_display

    buf = io.StringIO()
    bar = progress_display(Console(file=buf, width=80), "x")
    assert isinstance(bar, LineProgress)
    with bar:
        task = bar.add_task("render", total=20)
        for _ in range(20):
            bar.advance(task)
    lines = buf.getvalue().splitlines()
    assert lines[-1].startswith("render: 100% (20/20)") and "elapsed" in lines[-1] and "left" in lines[-1]
    assert 1 <= len(lines) <= 10  # a line a tenth at most, and the last one always
def test_single_task_checkpoints_are_evaluated_on_their_own_task(tmp_path, library):
    """A TD3 checkpoint runs its reward task only; an imitation-trained one tracks the clips with NEAR's metrics."""
    from fbcpr.core.checkpoint import save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.eval.agents import SingleTaskAgent
    from fbcpr.methods.td3.model import TD3Model

    def checkpoint(name, reward):
        cfg = config_from_dict({"algorithm": "td3", "agent": {"reward": reward},
                                "model": {"hidden_dim": 16, "hidden_layers": 1, "obs_dim": 358, "action_dim": 69}})
        return str(save_checkpoint(tmp_path / name, TD3Model(cfg.model), cfg))

    agent = make_agent(checkpoint("task", {"task": "move-ego-0-0"}))
    assert isinstance(agent, SingleTaskAgent) and isinstance(agent, Agent) and agent.task == "move-ego-0-0"
    assert agent.act(np.zeros((2, 358), np.float32), agent.reward_z("move-ego-0-0")).shape == (2, 69)
    res = evaluate(agent, episodes=1, steps=3, motions=library, show_progress=False)
    assert list(res["reward"]) == ["move-ego-0-0"] and "goal" not in res and "tracking" not in res

    agent = make_agent(checkpoint("amp", {"imitation": "amp"}))
    res = evaluate(agent, episodes=1, steps=3, motions=library, show_progress=False)
    assert "reward" not in res and set(res["tracking"]) == {"stand", "tpose"}
    for clip in res["tracking"].values():
        assert clip["dtw"] >= 0 and clip["sparc"] <= 0 and clip["sparc_expert"] <= 0
    assert res["summary"]["tracking"]["dtw"] == np.mean([c["dtw"] for c in res["tracking"].values()])
