"""Config: YAML onto typed dataclasses; every bad key or value names itself."""
from pathlib import Path

import pytest
import yaml

from fbcpr.core.checkpoint import load_checkpoint, save_checkpoint
from fbcpr.core.config import config_from_dict, find_config, load_config
from fbcpr.core.errors import ConfigError
from fbcpr.core.registry import get_method
from fbcpr.core.schema import PRESETS, dump_config

CONFIGS = Path(__file__).resolve().parents[1] / "fbcpr" / "configs"


@pytest.mark.parametrize("data, key", [
    ({"agent": {"discount_factor": 0.9}}, "agent.discount_factor"),
    ({"trainer": {}}, "trainer"),
    ({"agent": {"discount": 1.5}}, "agent.discount"),
    ({"agent": {"batch_size": "big"}}, "agent.batch_size"),
    ({"agent": {"batch_size": 100}}, "agent.batch_size"),          # not a multiple of seq_length
    ({"agent": {"relabel_prob": -0.1}}, "agent.relabel_prob"),
    ({"agent": {"z_expert": 0.5}}, "agent.z_expert"),              # nu does not sum to 1
    ({"model": {"preset": "huge"}}, "model.preset"),
    ({"model": {"hidden_dim": 33}}, "model.hidden_dim"),
    ({"model": {"z_dim": True}}, "model.z_dim"),
    ({"env": {"name": "atari"}}, "env.name"),
    ({"env": {"reset_fallen_s": -1.0}}, "env.reset_fallen_s"),
    ({"env": {"name": "toy", "reset_fallen_s": 1.0}}, "env.reset_fallen_s"),  # only the humanoid falls
    ({"env": {"fallen_terminates": True}}, "env.fallen_terminates"),          # without reset_fallen_s
    ({"env": {"reset_fallen_once_up": True}}, "env.reset_fallen_once_up"),    # without reset_fallen_s
    ({"env": {"fall_prob": 0.5, "stand_prob": 0.6}}, "env.stand_prob"),      # probabilities beyond 1
    ({"env": {"fall_prob": 0.5, "stand_prob": 0.3, "focus_prob": 0.3, "focus_clips": ["getup"]}}, "env.focus_prob"),
    ({"env": {"focus_prob": 0.3}}, "env.focus_clips"),                        # a share without clips
    ({"env": {"focus_clips": ["getup"]}}, "env.focus_clips"),                 # clips without a share
    ({"env": {"name": "toy", "focus_prob": 0.3, "focus_clips": ["a"]}}, "env.focus_clips"),  # humanoid only
    ({"train": {"device": "tpu"}}, "train.device"),
    ({"train": {"lr": float("nan")}}, "train.lr"),
    ({"env": {"name": "toy"}, "train": {"eval_every": 10, "eval_upright": 4}}, "train.eval_upright"),  # no humanoid
    ({"train": {"eval_upright": 4}}, "train.eval_upright"),                                  # never evaluated
    ({"train": {"eval_at_start": True}}, "train.eval_at_start"),                             # nothing periodic
    ({"train": {"eval_every": 10, "eval_upright": 4, "reward_buffer_size": 0}}, "train.eval_upright"),  # no prompt
    ({"train": {"eval_every": 10, "keep_best": "upright_s"}}, "train.keep_best"),            # not an eval/ metric
    ({"train": {"keep_best": "eval/tracking_emd"}}, "train.keep_best"),                     # never evaluated
    ({"train": {"eval_every": 10, "keep_best": "eval/upright_s"}}, "train.keep_best"),       # never measured
    ({"train": {"eval_every": 10, "keep_best": "eval/x", "keep_best_mode": "top"}}, "train.keep_best_mode"),
    ({"train": {"eval_every": 10, "keep_best_requires": {"eval/x": 1}}}, "train.keep_best_requires"),  # no keep_best
    ({"train": {"eval_every": 10, "keep_best": "eval/x", "keep_best_requires": {"x": 1}}},
     "train.keep_best_requires"),                                                         # not an eval/ metric
    ({"train": {"eval_every": 10, "keep_best": "eval/x", "keep_best_requires": {"eval/upright_s": 10}}},
     "train.keep_best_requires"),                                                         # never measured
    ({"train": {"eval_every": 10, "keep_best": "eval/x", "keep_best_requires": {"eval/y": "high"}}},
     "train.keep_best_requires"),                                                         # not a number
    ({"train": {"eval_every": 10, "keep_best": "eval/x", "keep_best_requires": ["eval/y"]}},
     "train.keep_best_requires"),                                                         # not a mapping
    ({"model": [1, 2]}, "model"),
    ({"train": {"eval_every": 10, "eval_tasks": "jump-2"}}, "train.eval_tasks"),            # not a list
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2", 3]}}, "train.eval_tasks"),       # not all names
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2", "fly-9"]}}, "train.eval_tasks"),  # unknown task
    ({"train": {"eval_every": 10, "eval_tasks": ["t_pose", "t_pose"]}}, "train.eval_tasks"),  # twice
    ({"train": {"eval_tasks": ["jump-2"]}}, "train.eval_tasks"),                             # never evaluated
    ({"env": {"name": "toy"}, "train": {"eval_every": 10, "eval_tasks": ["jump-2"]}}, "train.eval_tasks"),
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2"], "reward_buffer_size": 0}}, "train.eval_tasks"),
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2"], "eval_episodes": 0}}, "train.eval_episodes"),
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2"], "keep_best": "eval/return/sitonground"}},
     "train.keep_best"),                                                                   # not rolled out
    ({"train": {"eval_every": 10, "eval_tasks": ["jump-2"], "keep_best": "eval/goal_success"}}, "train.keep_best"),
])
def test_errors_name_the_key(data, key):
    with pytest.raises(ConfigError) as e:
        config_from_dict(data)
    assert str(e.value).startswith(key)


def test_eval_tasks_is_a_list_of_names_that_keep_best_may_name(tmp_path):
    cfg = config_from_dict({"train": {"eval_every": 10, "eval_tasks": ["jump-2", "t_pose"],
                                      "keep_best": "eval/goal_success"}})
    assert cfg.train.eval_tasks == ["jump-2", "t_pose"] and config_from_dict({}).train.eval_tasks == []
    for metric in ("eval/return/jump-2", "eval/goal/t_pose"):
        assert config_from_dict({"train": {"eval_every": 10, "eval_tasks": ["jump-2", "t_pose"],
                                           "keep_best": metric}}).train.keep_best == metric
    (tmp_path / "c.yaml").write_text(dump_config(cfg))
    assert load_config(tmp_path / "c.yaml").train.eval_tasks == ["jump-2", "t_pose"]  # saved configs load again


def test_defaults_are_the_paper_values():
    cfg = config_from_dict({})
    a, t = cfg.agent, cfg.train
    assert (a.batch_size, a.seq_length, a.discount, a.tau, a.relabel_prob) == (1024, 8, 0.98, 0.005, 0.8)
    assert (a.lr_f, a.lr_b, a.lr_actor, a.lr_critic, a.lr_discriminator) == (1e-4, 1e-5, 1e-4, 1e-4, 1e-5)
    assert (a.ortho_coef, a.fz_coef, a.actor_reg_coef, a.grad_penalty) == (100, 0.1, 0.01, 10)
    assert (a.fb_pessimism, a.actor_pessimism, a.critic_pessimism) == (0, 0.5, 0.5)
    assert (a.z_expert, a.z_online, a.z_uniform) == (0.6, 0.2, 0.2)
    assert (t.num_envs, t.rollout_steps, t.updates_per_rollout, t.warmup_steps, t.buffer_capacity) == (50, 500, 50, 50_000, 5_000_000)
    assert (t.z_update_every, t.priority_every, cfg.env.fall_prob) == (150, 1_000_000, 0.2)
    assert cfg.model.z_dim == 256 and cfg.model.hidden_dim == 1024


def test_preset_then_overrides_and_roundtrip(tmp_path):
    cfg = config_from_dict({"model": {"preset": "tiny", "z_dim": 12}, "agent": {"lr_f": 3}})
    assert cfg.model.z_dim == 12 and cfg.model.hidden_dim == PRESETS["tiny"]["hidden_dim"]
    assert cfg.agent.lr_f == 3.0 and isinstance(cfg.agent.lr_f, float)
    p = tmp_path / "c.yaml"
    p.write_text(dump_config(cfg))
    assert load_config(p) == cfg


def test_a_saved_run_names_its_clips_under_the_data_directory_wherever_it_is_read(tmp_path, monkeypatch):
    """A run's config.yaml writes data-directory paths as `$FBCPR_DATA/...` (not this machine's folders), and
    loading the checkpoint where FBCPR_DATA names another folder finds the clips there; other paths are kept."""
    monkeypatch.setenv("FBCPR_DATA", str(tmp_path / "here"))
    cfg = load_config(find_config("virl-walk"))
    cfg.env.focus_motions, cfg.env.focus_prob = str(tmp_path / "own" / "rises"), 0.1
    cfg.model.obs_dim, cfg.model.action_dim, cfg.model.hidden_dim = 8, 3, 32
    model = get_method(cfg.algorithm).model(cfg.model)
    ckpt = save_checkpoint(tmp_path / "run", model, cfg)
    saved = yaml.safe_load((ckpt / "config.yaml").read_text())
    assert saved["env"]["motions"] == "$FBCPR_DATA/clips/deepmimic/walk.npz"
    assert saved["agent"]["virl"]["multitask"] == "$FBCPR_DATA/clips/deepmimic"
    assert saved["env"]["focus_motions"] == str(tmp_path / "own" / "rises")
    monkeypatch.setenv("FBCPR_DATA", str(tmp_path / "there"))
    loaded = load_checkpoint(ckpt).config
    assert loaded.env.motions == str(tmp_path / "there" / "clips" / "deepmimic" / "walk.npz")
    assert loaded.agent.virl.multitask == str(tmp_path / "there" / "clips" / "deepmimic")
    assert loaded.env.focus_motions == str(tmp_path / "own" / "rises")


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIGS.glob("*.yaml")))
def test_shipped_configs_load(name):
    load_config(CONFIGS / f"{name}.yaml")


def test_paper_presets_have_two_hidden_trunk_layers():
    assert load_config(CONFIGS / "paper-S.yaml").model.hidden_layers == 2


def test_bad_yaml_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("model: {z_dim: [")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_config(p)
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.yaml")


def test_invalid_yaml_names_line_and_column(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("model:\n  z_dim: 8\nagent:\n  batch_size: [1, 2\n")
    with pytest.raises(ConfigError, match=rf"{p.name}:\d+:\d+: invalid YAML") as err:
        load_config(p)
    assert "\n" not in str(err.value)


def test_relative_paths_are_read_from_the_config_folder(tmp_path, monkeypatch):
    (tmp_path / "proj" / "configs").mkdir(parents=True)
    p = tmp_path / "proj" / "configs" / "mine.yaml"
    p.write_text("env:\n  motions: ../data/clips\n")
    monkeypatch.chdir(tmp_path)
    assert load_config(p).env.motions == str(tmp_path / "proj" / "data" / "clips")
    p.write_text("env:\n  motions: synthetic\n")
    assert load_config(p).env.motions == "synthetic"


def test_shipped_configs_are_found_by_name(tmp_path, monkeypatch):
    from fbcpr.core.config import find_config

    monkeypatch.chdir(tmp_path)
    assert find_config("small").name == "small.yaml" and find_config("toy.yaml").is_file()
    with pytest.raises(ConfigError, match="did you mean 'small'"):
        find_config("smal")
    (tmp_path / "small").mkdir()           # a local folder of that name is not a config; the shipped one is
    assert find_config("small").parent.name == "configs"


def test_env_of_a_model_only_config_is_the_default_humanoid():
    from fbcpr.core.schema import ModelConfig, env_of

    toy = config_from_dict({"env": {"name": "toy"}})
    assert env_of(toy) is toy.env and env_of(toy).name == "toy"
    assert env_of(ModelConfig()).name == "humanoid" and env_of(ModelConfig()).action_mapping == "rest"


def test_shipped_configs_read_clips_from_the_data_directory(tmp_path, monkeypatch):
    """An installed package's configs cannot point into a source tree: `$FBCPR_DATA/...` names the data directory,
    the environment variable's folder, else `data` in the working directory."""
    monkeypatch.delenv("FBCPR_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    assert load_config(find_config("cpu")).env.motions == str(tmp_path / "data" / "clips" / "mixed")
    monkeypatch.setenv("FBCPR_DATA", str(tmp_path / "elsewhere"))
    cfg = load_config(find_config("virl-walk"))
    assert cfg.env.motions == str(tmp_path / "elsewhere" / "clips" / "deepmimic" / "walk.npz")
    assert cfg.agent.virl.multitask == str(tmp_path / "elsewhere" / "clips" / "deepmimic")


def test_other_relative_paths_stay_relative_to_the_config_file(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_DATA", str(tmp_path / "d"))
    (tmp_path / "proj").mkdir()
    p = tmp_path / "proj" / "mine.yaml"
    p.write_text("env:\n  motions: clips/a.npz\n  focus_motions: ${FBCPR_DATA}/rises\n  focus_prob: 0.1\n")
    cfg = load_config(p)
    assert cfg.env.motions == str(tmp_path / "proj" / "clips" / "a.npz")
    assert cfg.env.focus_motions == str(tmp_path / "d" / "rises")


@pytest.mark.parametrize("name", sorted(p.stem for p in CONFIGS.glob("*.yaml")))
def test_shipped_configs_split_over_1_2_4_and_8_processes(name):
    """`torchrun --nproc_per_node=N -m fbcpr train NAME` runs for N in 1, 2, 4, 8: each phase's global env steps
    are the same as one process's, so the update-to-data ratio does not change with N."""
    import math

    from fbcpr.train.schedule import check_world_size, phase_steps

    cfg = load_config(CONFIGS / f"{name}.yaml")
    for world in (1, 2, 4, 8):
        check_world_size(cfg, world)
        assert phase_steps(cfg.train, world) * world == math.ceil(cfg.train.rollout_steps / cfg.train.num_envs)


@pytest.mark.parametrize("data, message", [
    ({"model": {"presett": "tiny"}}, "model.presett: unknown key (did you mean 'preset'?"),
    ({"agnet": {"batch_size": 8}}, "agnet: unknown key (did you mean 'agent'?"),
    ({"train": {"num_env": 4}}, "train.num_env: unknown key (did you mean 'num_envs'?"),
])
def test_a_misspelt_key_gets_a_suggestion(data, message):
    with pytest.raises(ConfigError) as err:
        config_from_dict(data)
    assert str(err.value).startswith(message)


def test_the_model_keys_listed_include_preset():
    with pytest.raises(ConfigError) as err:
        config_from_dict({"model": {"zzz": 1}})
    assert "preset" in str(err.value).split("valid keys:")[1] and "did you mean" not in str(err.value)
