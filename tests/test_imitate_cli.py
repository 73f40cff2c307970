"""`fbcpr imitate`: a short toy run writes a checkpoint; bad DEMO / --reward give one-line errors."""
from typer.testing import CliRunner

from fbcpr.cli.app import app
from fbcpr.cli.imitate_cmd import imitation_config
from fbcpr.core.registry import IMITATION_REWARDS


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})


def test_imitate_a_toy_demo_writes_a_checkpoint(tmp_path):
    res = run("imitate", "circle-ccw", "--reward", "virl", "--out", tmp_path / "r", "--steps", 300, "--no-progress")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "r" / "checkpoints" / "latest").is_file() and "DTW to circle-ccw" in res.output
    again = run("imitate", "circle-ccw", "--reward", "virl", "--out", tmp_path / "r", "--steps", 300)
    assert again.exit_code == 1 and "already holds a run" in again.output


def test_imitate_errors_name_the_bad_argument(tmp_path):
    res = run("imitate", tmp_path / "missing.npz", "--reward", "virl", "--out", tmp_path / "r")
    assert res.exit_code == 1 and "DEMO" in res.output and "does not exist" in res.output
    res = run("imitate", "circle-ccw", "--reward", "nope", "--out", tmp_path / "r")
    assert res.exit_code == 1 and "--reward" in res.output and "'nope'" in res.output
    assert not (tmp_path / "r").exists()
    (tmp_path / "frames").mkdir()
    res = run("imitate", tmp_path / "frames", "--reward", "amp", "--out", tmp_path / "r")
    assert res.exit_code == 1 and "folder of frames" in res.output


def test_every_registered_reward_has_a_toy_config_and_frames_go_to_video(tmp_path):
    for name in IMITATION_REWARDS:
        cfg, kind = imitation_config("circle-ccw", name)
        assert kind == "toy" and cfg.agent.reward.imitation == name and cfg.env.motions == "circle-ccw"
    (tmp_path / "frames").mkdir()
    cfg, kind = imitation_config(str(tmp_path / "frames"), "virl")
    assert kind == "toy-video" and cfg.agent.virl.input == "video" and cfg.agent.virl.demo_frames == str(tmp_path / "frames")


def test_imitate_resume_continues_the_run_and_refuses_what_it_cannot(tmp_path):
    from fbcpr.train.trainer import checkpoint_env_steps

    out = tmp_path / "r"
    res = run("imitate", "circle-ccw", "--reward", "amp", "--out", out, "--more-steps", 100)
    assert res.exit_code == 1 and "needs --resume" in res.output and not out.exists()
    res = run("imitate", "circle-ccw", "--reward", "amp", "--out", out, "--resume")
    assert res.exit_code == 1 and "no checkpoint to resume" in res.output
    assert run("imitate", "circle-ccw", "--reward", "amp", "--out", out, "--steps", 300,
               "--no-progress").exit_code == 0
    first = checkpoint_env_steps(out)
    res = run("imitate", "circle-ccw", "--reward", "amp", "--out", out, "--resume", "--more-steps", 200,
              "--no-progress")
    assert res.exit_code == 0, res.output
    assert checkpoint_env_steps(out) >= first + 200 and "finished at" in res.output
    res = run("imitate", "circle-ccw", "--reward", "amp", "--out", out, "--resume", "--steps", first)
    assert res.exit_code == 0 and "nothing to do" in res.output
