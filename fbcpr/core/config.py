"""Reading a run configuration: YAML onto the schema (`fbcpr.core.schema`), with the checks that span sections.

`algorithm` picks the `agent:` section's schema through the registry. Paths in a config are taken from the
config file's folder, except those under the data directory: `$FBCPR_DATA/clips/mixed` reads from the folder
that the environment variable FBCPR_DATA names (default: `data` in the working directory), so the configs that
ship inside the installed package find a user's clips.
"""
from __future__ import annotations

import copy
import dataclasses
import difflib
import os
import typing
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from fbcpr.core.errors import ConfigError
from fbcpr.core.registry import env_kind, get_method
from fbcpr.core.schema import Config, ModelConfig, TrainConfig, _build

#: The environment variable naming the data directory, and the name a config's paths use for it.
DATA_VAR = "FBCPR_DATA"


def data_dir() -> Path:
    """The data directory: $FBCPR_DATA, else `data` in the working directory (where `fbcpr motions import` and
    the README put clips)."""
    return Path(os.environ.get(DATA_VAR) or "data").expanduser().resolve()


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a Config from plain data (as loaded from YAML); `algorithm` picks the `agent:` schema."""
    algorithm = data.get("algorithm", Config.algorithm) if isinstance(data, dict) else Config.algorithm
    if not isinstance(algorithm, str):
        raise ConfigError(f"algorithm: expected str, got {algorithm!r}")
    cfg = _build(Config, data, "", sections={"agent": get_method(algorithm).agent_config()})
    env_kind(cfg.env.name)
    if cfg.env.reset_fallen_s and cfg.env.name != "humanoid":
        raise ConfigError(f"env.reset_fallen_s: only the humanoid falls; set it to 0 for env.name {cfg.env.name!r}")
    if cfg.env.fall_prob + cfg.env.stand_prob > 1.0 + 1e-9:
        raise ConfigError(f"env.stand_prob: env.fall_prob + env.stand_prob must be <= 1, got "
                          f"{cfg.env.fall_prob} + {cfg.env.stand_prob}")
    if cfg.env.fall_prob + cfg.env.stand_prob + cfg.env.focus_prob > 1.0 + 1e-9:
        raise ConfigError(f"env.focus_prob: env.fall_prob + env.stand_prob + env.focus_prob must be <= 1, got "
                          f"{cfg.env.fall_prob} + {cfg.env.stand_prob} + {cfg.env.focus_prob}")
    if cfg.env.focus_clips and cfg.env.focus_motions:
        raise ConfigError("env.focus_motions: focus starts come from env.focus_clips or from env.focus_motions, not "
                          "both")
    focus_key = "env.focus_motions" if cfg.env.focus_motions else "env.focus_clips"
    if bool(cfg.env.focus_prob) != bool(cfg.env.focus_clips or cfg.env.focus_motions):
        raise ConfigError(f"{focus_key}: give focus clips (env.focus_clips or env.focus_motions) together with "
                          f"env.focus_prob > 0 (one without the other does nothing), got focus_prob "
                          f"{cfg.env.focus_prob}")
    if (cfg.env.focus_clips or cfg.env.focus_motions) and cfg.env.name != "humanoid":
        raise ConfigError(f"{focus_key}: starts on chosen clips are a humanoid option")
    for key in ("fallen_terminates", "reset_fallen_once_up"):
        if getattr(cfg.env, key) and not cfg.env.reset_fallen_s:
            raise ConfigError(f"env.{key}: needs env.reset_fallen_s > 0 (how long fallen ends an episode)")
    tc = cfg.train
    for key in ("eval_upright", "eval_tasks"):  # the policy evaluations prompt the humanoid at each evaluation
        if not getattr(tc, key):
            continue
        if cfg.env.name != "humanoid" or not tc.eval_every:
            raise ConfigError(f"train.{key}: rolls out the humanoid at each evaluation; needs env.name humanoid and "
                              "train.eval_every > 0")
        if get_method(cfg.algorithm).promptable and not tc.reward_buffer_size:
            raise ConfigError(f"train.{key}: prompting a reward needs a reward-inference sample; set "
                              "train.reward_buffer_size > 0")
    _check_eval_tasks(tc.eval_tasks)
    if tc.eval_at_start and not tc.eval_every:
        raise ConfigError("train.eval_at_start: needs train.eval_every > 0 (what to evaluate is set for the periodic "
                          "evaluations)")
    if tc.keep_best_requires and not tc.keep_best:
        raise ConfigError("train.keep_best_requires: minimums for the best checkpoint need train.keep_best")
    for key, metric in [("keep_best", tc.keep_best)] + [("keep_best_requires", m) for m in tc.keep_best_requires]:
        _check_logged(tc, key, metric)
    if tc.demonstration_share and not tc.demonstrations:
        raise ConfigError("train.demonstration_share: draws from train.demonstrations, which is not set")
    if tc.demonstration_share and tc.demonstration_copies != 1:
        raise ConfigError("train.demonstration_copies: copies go into the replay buffer; with "
                          "train.demonstration_share the demonstrations are held apart (leave it at 1)")
    cfg.agent.validate_run(cfg)
    return cfg


def _check_eval_tasks(names: list[str]) -> None:
    """`train.eval_tasks` names humanoid reward tasks or goal poses, each once."""
    if not names:
        return
    from humanoid_env.tasks import GOALS, get_reward

    for name in names:
        if name in GOALS:
            continue
        try:
            get_reward(name)
        except ValueError as err:
            raise ConfigError(f"train.eval_tasks: {name!r} is neither a reward task nor a goal pose ({err})") from None
    if len(set(names)) != len(names):
        raise ConfigError(f"train.eval_tasks: a name is given twice in {names}")


def _check_logged(tc: TrainConfig, key: str, metric: str) -> None:
    """`train.<key>` names `metric`, which the run's evaluations must log (custom eval hooks' metrics pass)."""
    if not metric:
        return
    if not tc.eval_every:
        raise ConfigError(f"train.{key}: {metric!r} comes from evaluations; set train.eval_every > 0")
    if metric.startswith("eval/upright") and not tc.eval_upright:
        raise ConfigError(f"train.{key}: {metric!r} is logged only with train.eval_upright > 0")
    if metric.startswith(("eval/return/", "eval/goal")) and not _logs_task_metric(tc, metric):
        raise ConfigError(f"train.{key}: {metric!r} is logged only for a reward task or goal pose of "
                          f"train.eval_tasks (now {tc.eval_tasks})")


def _logs_task_metric(tc: TrainConfig, metric: str) -> bool:
    """Whether `metric` is an eval/return/ or eval/goal metric that `train.eval_tasks` logs."""
    from humanoid_env.tasks import GOALS

    goals = [n for n in tc.eval_tasks if n in GOALS]
    logged = {f"eval/return/{n}" for n in tc.eval_tasks if n not in GOALS} | {f"eval/goal/{n}" for n in goals}
    return metric in logged | ({"eval/goal_success"} if goals else set())


def model_config_from_dict(data: dict[str, Any]) -> ModelConfig:
    """Validate a bare `model:` section (used by checkpoints)."""
    return _build(ModelConfig, data, "model")


class _UniqueKeyLoader(yaml.SafeLoader):
    """safe_load that rejects a key given twice in one mapping: YAML would silently keep the last one."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, typing.Hashable):
                continue  # SafeLoader names an unhashable key itself
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def load_config(path: str | Path) -> Config:
    """Read a YAML config file (safe_load only); relative paths in it are taken from the file's folder, so a
    config works from any working directory."""
    path = Path(path)
    try:
        data = yaml.load(path.read_bytes().decode("utf-8"), Loader=_UniqueKeyLoader)
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a config file") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror})") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text (invalid byte at offset {e.start})") from None
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        raise ConfigError(f"{where}: invalid YAML: {e.problem or e.context}") from None
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: invalid YAML ({e})") from None
    cfg = config_from_dict(data or {})
    for part, key, value in _paths(cfg):
        setattr(part, key, str(resolve_path(value, path.parent)))
    return cfg


def resolve_path(value: str, base: Path) -> Path:
    """A config path as a file system path: `$FBCPR_DATA/...` under the data directory, other relative paths
    under `base` (the config file's folder)."""
    inside = _in_data_dir(value)
    if inside is not None:
        return data_dir() / inside
    return (base / Path(value).expanduser()).resolve()


def _in_data_dir(value: str) -> str | None:
    """What follows `$FBCPR_DATA/` (or `${FBCPR_DATA}/`) in a config path, "" for the data directory itself, and
    None for a path written any other way."""
    for prefix in (f"${DATA_VAR}", f"${{{DATA_VAR}}}"):
        if value == prefix or value.startswith(prefix + "/"):
            return value[len(prefix):].lstrip("/")
    return None


def data_relative_config(cfg: Config) -> Config:
    """A copy whose paths under the data directory are written `$FBCPR_DATA/...`, as the shipped configs write
    them, so that a saved run read on another machine (or with another FBCPR_DATA) finds its clips there."""
    out = copy.deepcopy(cfg)
    _rewrite_under(out, data_dir(), lambda inside: f"${DATA_VAR}" if inside == "." else f"${DATA_VAR}/{inside}")
    return out


def expand_data_paths(cfg: Config) -> Config:
    """`cfg` with its `$FBCPR_DATA/...` paths under this machine's data directory (in place; other paths as
    they are): the inverse of `data_relative_config` for a config read back from a checkpoint."""
    for part, key, value in _paths(cfg):
        inside = _in_data_dir(value)
        if inside is not None:
            setattr(part, key, str(data_dir() / inside))
    return cfg


def _rewrite_under(cfg: Config, root: Path, write: Callable[[str], str]) -> None:
    """Every absolute path of `cfg` under `root` replaced (in place) by `write` of its part below `root`."""
    for part, key, value in _paths(cfg):
        target = Path(value).expanduser()
        if target.is_absolute() and target.is_relative_to(root):
            setattr(part, key, write(target.relative_to(root).as_posix()))


def _paths(cfg: Config) -> list[tuple[Any, str, str]]:
    """(section object, key, value) of every path `cfg` holds: the set fields marked `path` for its env, in every
    section, a method's and its rewards' included ("synthetic" names the built-in clips, not a path)."""
    out = []

    def walk(section: Any) -> None:
        for f in dataclasses.fields(section):
            value = getattr(section, f.name)
            if dataclasses.is_dataclass(value):
                walk(value)
            elif isinstance(value, str) and value != "synthetic" and f.metadata.get("path") in ("any", cfg.env.name):
                out.append((section, f.name, value))

    walk(cfg)
    return out


def portable_config(cfg: Config, base: str | Path = ".") -> Config:
    """A copy whose paths under the data directory are `$FBCPR_DATA/...` and those under `base` relative to it, so
    that a checkpoint made to be shared does not carry this machine's folders (paths elsewhere stay as they are:
    they were never portable)."""
    out = data_relative_config(cfg)
    _rewrite_under(out, Path(base).resolve(), lambda inside: inside)
    return out


def shipped_configs() -> dict[str, Path]:
    """The configs that ship inside the package (fbcpr.configs), by name."""
    folder = Path(str(resources.files("fbcpr.configs")))
    return {p.stem: p for p in sorted(folder.glob("*.yaml"))}


def find_config(spec: str | Path) -> Path:
    """A config file path, or the name of a shipped config (`small`, `quickstart.yaml`)."""
    path = Path(spec).expanduser()
    if path.is_file():
        return path
    shipped = shipped_configs()
    name = path.stem if path.suffix in ("", ".yaml", ".yml") and path.parent == Path(".") else None
    if name in shipped:
        return shipped[name]
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, not a config file")
    close = difflib.get_close_matches(path.stem, list(shipped), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise ConfigError(f"{spec}: no such config file, nor a shipped config ({', '.join(shipped)}){hint}")


