"""The run configuration's schema: nested dataclasses whose fields carry their own validators.

Unknown keys, wrong types and out-of-range values raise `ConfigError` naming the dotted key
(e.g. `agent.relabel_prob: must be in [0, 1], got 1.5`), so a typo never silently falls back to a default.
Defaults are the paper's values (App. C.5, Tables 3, 5-7, 9); `model.preset` picks a network size. A method's
`agent:` section is its own dataclass (a `MethodConfig`), found through the registry when a config is read.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import yaml

from fbcpr.core.errors import ConfigError
from humanoid_env.actions import ACTION_MAPPINGS, DEFAULT_ACTION_MAPPING


def _check(pred: Callable[[Any], bool], what: str) -> Callable[[Any], str | None]:
    return lambda v: None if pred(v) else what


def _range(lo: float, hi: float) -> Callable[[Any], str | None]:
    """Bounds that keep a value within what one machine can run: a typo like 10**9 envs fails here, naming its
    key, not minutes later inside an allocation."""
    return _check(lambda v: lo <= v <= hi, f"must be in [{lo:,}, {hi:,}]")


POSITIVE = _check(lambda v: v > 0, "must be > 0")
NON_NEGATIVE = _check(lambda v: v >= 0, "must be >= 0")
PROB = _check(lambda v: 0.0 <= v <= 1.0, "must be in [0, 1]")


def _f(default: Any, check: Callable[[Any], str | None] | None = None, path: str | None = None, **kw: Any) -> Any:
    """A dataclass field with an optional validator stored in its metadata. `path`: the field holds a file or
    folder path for the env of that name ("any": every env), which reading a config file resolves."""
    meta = {"check": check, "path": path}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda: type(default)(default), metadata=meta, **kw)
    return field(default=default, metadata=meta, **kw)


@dataclass
class MethodConfig:
    """Base of a method's `agent:` section (config_from_dict puts the named method's own there). `validate_run` checks
    what the section needs of the rest of the run (other sections), after every section was read on its own."""

    def validate_run(self, run: Config) -> None:
        """ConfigError naming the key when this method cannot run with `run`'s other sections."""

    def holds_loaded_model(self) -> list[str]:
        """The keys set in this section that hold a run near the model it continues (they need --init-from)."""
        return []


@runtime_checkable
class BatchConfig(Protocol):
    """What the online trainer reads of every method's `agent:` section (each method declares both, with its own
    defaults and checks): update batches of `batch_size` transitions and demonstration windows of `seq_length`."""

    batch_size: int
    seq_length: int


def batch_config(agent: MethodConfig) -> BatchConfig:
    """A method's `agent:` section as the trainer reads it."""
    assert isinstance(agent, BatchConfig), f"{type(agent).__name__}: a method section needs batch_size and seq_length"
    return agent


def check_windows(batch_size: int, seq_length: int) -> None:
    """A batch is cut into demonstration windows of `seq_length`: ConfigError unless they divide it."""
    if batch_size % seq_length:
        raise ConfigError(f"agent.batch_size: must be a multiple of agent.seq_length ({seq_length}), got {batch_size}")


@dataclass
class ModelConfig:
    """Network sizes (Tables 5-7). obs_dim/action_dim may be left null and are then taken from the env."""

    obs_dim: int | None = _f(None, POSITIVE)
    action_dim: int | None = _f(None, POSITIVE)
    z_dim: int = _f(256, _range(1, 4096))
    hidden_dim: int = _f(1024, _check(lambda v: 2 <= v <= 16384 and v % 2 == 0, "must be an even int in [2, 16,384]"))
    hidden_layers: int = _f(1, _range(0, 64))
    embedding_layers: int = _f(2, _range(2, 64))
    backward_hidden_dim: int = _f(256, _range(1, 16384))
    backward_hidden_layers: int = _f(1, _range(1, 64))
    discriminator_hidden_dim: int = _f(1024, _range(1, 16384))
    discriminator_hidden_layers: int = _f(3, _range(1, 64))
    ensemble_size: int = _f(2, _range(1, 64))
    actor_std: float = _f(0.2, POSITIVE)
    actor_noise_clip: float = _f(0.3, POSITIVE)
    norm_obs: bool = _f(True)
    norm_eps: float = _f(1e-5, POSITIVE)


@dataclass
class EnvConfig:
    """Which environment and demonstrations; the trainer only sees what `fbcpr.envs.bundle.make_env` builds."""

    name: str = _f("humanoid")  # an env kind of the registry (`fbcpr.core.registry.ENVS`), checked on load
    # humanoid: a folder of clips or one clip .npz; toy: "synthetic" (all demos) or demo names
    motions: str = _f("synthetic", path="humanoid")
    fall_prob: float = _f(0.2, PROB)
    stand_prob: float = _f(0.0, PROB)  # humanoid: share of training episodes that start from the standing rest pose
    # humanoid: share of training episodes that start on a frame of the clips named in focus_clips (reference-state
    # starts along a skill, e.g. [getup_facedown]: rising from half-way up is reachable by exploration)
    focus_prob: float = _f(0.0, PROB)
    focus_clips: list[str] = _f([])
    # humanoid: or draw those starts from the frames of other clips, a clip .npz or a folder of them, e.g. the sampling
    # planner's getting-up demonstrations (motions.demonstrations): states the body really passes through on a rise
    # that works, velocities included, where a mocap clip's frames are only kinematic
    focus_motions: str | None = _f(None, path="humanoid")
    max_episode_steps: int = _f(300, _range(1, 10**7))
    action_mapping: str = _f(DEFAULT_ACTION_MAPPING,
                             _check(lambda v: v in ACTION_MAPPINGS, f"must be one of {ACTION_MAPPINGS}"))
    # humanoid: truncate a training episode (not terminate: no reward or objective changes) once the pelvis has
    # been below 0.6 m this many seconds in a row, so the buffer holds more upright states and fewer of lying
    # still; 0 = off (the paper). Evaluation episodes always run their full length.
    reset_fallen_s: float = _f(0.0, _range(0.0, 3600.0))
    # ... and end it as a termination instead: lying fallen becomes an absorbing state worth 0, which changes the
    # objective (single-task agents on rewards >= 0 then value staying up; lying-down tasks become unlearnable)
    fallen_terminates: bool = _f(False)
    # ... and start that clock only once the pelvis has been above 0.6 m for reset_fallen_s in a row in this
    # episode: a fall start (which is dropped from up to 1 m and lies at once) keeps its whole episode to get up
    reset_fallen_once_up: bool = _f(False)
    # reuse (fbcpr.apps.npmp.reuse): an NPMP checkpoint whose frozen decoder turns actions in its latent space into the
    # env's actions; the agent then acts with the AR(1) prior's innovation eps = npmp_innovation_scale * a
    npmp: str | None = _f(None, path="any")
    npmp_innovation_scale: float = _f(math.sqrt(3.0), POSITIVE)  # sqrt(3): uniform actions have unit variance


@dataclass
class TrainConfig:
    """Online loop (Tables 3, 4, 9): rollouts, update ratio, buffer, priorities, logging, checkpoints."""

    seed: int = _f(0, NON_NEGATIVE)
    device: str = _f("cpu", _check(lambda v: v == "cpu" or v.startswith("cuda") or v == "auto",
                                   "must be cpu, cuda[:i] or auto"))
    total_env_steps: int = _f(30_000_000, POSITIVE)
    num_envs: int = _f(50, _range(1, 4096))
    warmup_steps: int = _f(50_000, NON_NEGATIVE)
    rollout_steps: int = _f(500, _range(1, 10**7))
    updates_per_rollout: int = _f(50, _range(0, 10**7))
    buffer_capacity: int = _f(5_000_000, _range(1, 10**9))
    buffer_memmap_mb: float = _f(2048.0, NON_NEGATIVE)
    # also keep the replay buffer's training fields and the motion frames on train.device, and draw every update's
    # batch there (fbcpr.train.device_batches): on a GPU the host then neither gathers nor copies batches. Costs the
    # buffer's fields once more in device memory; not with sequence rewards (agents that read state histories)
    device_buffer: bool = _f(False)
    z_update_every: int = _f(150, POSITIVE)
    priority_every: int = _f(1_000_000, NON_NEGATIVE)
    priority_max_clips: int = _f(256, _range(1, 10**6))
    eval_every: int = _f(0, NON_NEGATIVE)
    # also evaluate once before the first rollout, at env step 0: a run continued with --init-from then logs the
    # model it starts from on the same starts as every later evaluation, and that model competes for keep_best
    eval_at_start: bool = _f(False)
    # humanoid: each evaluation also measures the median seconds upright under the stand prompt over this many
    # standing and pushed standing starts (eval/upright_s, eval/upright_pushed_s) and the share of as many fall
    # starts that got up (eval/got_up; fbcpr.eval.upright)
    eval_upright: int = _f(0, _range(0, 4096))
    # humanoid: each evaluation also rolls out these reward tasks and goal poses (names as `fbcpr eval --tasks`)
    # for eval_episodes episodes from the same test starts every time, and logs eval/return/<task>,
    # eval/goal/<pose> (success) and eval/goal_success: curves of returns and goal success against steps
    eval_tasks: list[str] = _f([])
    eval_episodes: int = _f(8, _range(1, 4096))
    # an evaluation metric (e.g. eval/upright_pushed_s) whose best value's checkpoint checkpoints/best names and
    # retention spares: a policy that unlearns a skill later in the run keeps its best checkpoint
    keep_best: str = _f("", _check(lambda v: v == "" or v.startswith("eval/"), "must be '' or an eval/ metric"))
    keep_best_mode: str = _f("max", _check(lambda v: v in ("max", "min"), "must be 'max' or 'min'"))
    # minimum values an evaluation must reach to compete for checkpoints/best, e.g. {eval/upright_s: 10,
    # eval/upright_pushed_s: 10}: the best walk among evaluations that still stand, not the best walk of a run whose
    # stand comes and goes
    keep_best_requires: dict[str, float] = _f({}, _check(lambda d: all(k.startswith("eval/") for k in d),
                                                         "must name eval/ metrics"))
    checkpoint_every: int = _f(1_000_000, NON_NEGATIVE)
    keep_checkpoints: int = _f(3, POSITIVE)
    keep_every: int = _f(0, NON_NEGATIVE)
    log_every: int = _f(10_000, POSITIVE)
    reward_buffer_size: int = _f(100_000, _range(0, 10**7))
    save_buffer: bool = _f(False)
    # a run continued with --init-from: every checkpoint carries the loaded model's reward-inference sample as it
    # is, so that with a frozen B (agent.freeze_backward) reward prompts infer the loaded model's z's
    keep_reward_sample: bool = _f(False)
    # humanoid: a folder of demonstrations with actions (motions.demonstrations, e.g. the sampling planner's getting
    # up, lab/experiments/getup_planner.py --save) whose transitions go into the replay buffer when a run starts (fresh
    # or --init-from), each demonstration_copies times: transitions that exploration has not found (as plain
    # transitions they made TD3's critic diverge)
    demonstrations: str | None = _f(None, path="humanoid")
    demonstration_copies: int = _f(1, _range(1, 1000))
    # > 0: the demonstrations are held apart from the replay buffer (never overwritten) and this share of every
    # update's batch is drawn from them, marked so that a loss can treat them apart (TD3's agent.bc_weight)
    demonstration_share: float = _f(0.0, _range(0.0, 0.5))
    torch_threads: int = _f(0, _range(0, 1024))
    # MuJoCo threads of the training envs; 0: all cores, split between the ranks of a torchrun on one machine.
    # Set it when other runs share the machine (e.g. several seeds on one GPU)
    env_threads: int = _f(0, _range(0, 1024))
    # sync: collect a rollout phase, then update (one process). async: `collectors` worker processes step the envs
    # (num_envs / collectors each) while the learner updates, at the same update-to-data ratio
    # (fbcpr.train.workers); each collector steps on train.env_threads MuJoCo threads (0: the cores shared by the
    # collectors and the learner)
    engine: str = _f("sync", _check(lambda v: v in ("sync", "async"), "must be sync or async"))
    collectors: int = _f(1, _range(1, 256))
    dist_timeout_s: float = _f(600.0, _range(1.0, 86_400.0))  # torchrun runs: a rank gone this long is an error
    dist_backend: str = _f("auto", _check(lambda v: v in ("auto", "nccl", "gloo"), "must be auto, nccl or gloo"))


@dataclass
class Config:
    """A whole run: the method (`algorithm`), model sizes, its hyperparameters, environment and training loop.

    `agent` holds the named method's hyperparameters (`fbcpr.core.registry`): `AgentConfig` for FB-CPR."""

    algorithm: str = _f("fb_cpr")
    model: ModelConfig = field(default_factory=ModelConfig)
    agent: MethodConfig = field(default_factory=MethodConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    train: TrainConfig = field(default_factory=TrainConfig)


#: Network-size presets (hidden sizes per Tables 5-7 for paper-S; paper-M doubles the width).
PRESETS: dict[str, dict[str, Any]] = {
    "tiny": dict(z_dim=8, hidden_dim=32, hidden_layers=1, backward_hidden_dim=32, discriminator_hidden_dim=32,
                 discriminator_hidden_layers=2),
    "small": dict(z_dim=64, hidden_dim=256, hidden_layers=1, backward_hidden_dim=128, discriminator_hidden_dim=256,
                  discriminator_hidden_layers=3),
    "paper-S": dict(z_dim=256, hidden_dim=1024, hidden_layers=2, backward_hidden_dim=256, discriminator_hidden_dim=1024,
                    discriminator_hidden_layers=3),
    "paper-M": dict(z_dim=256, hidden_dim=2048, hidden_layers=2, backward_hidden_dim=256, discriminator_hidden_dim=1024,
                    discriminator_hidden_layers=3),
}


def _type_ok(value: Any, tp: Any) -> tuple[bool, Any]:
    """Check (and gently coerce int->float) a YAML value against a field annotation."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None:
            return (type(None) in args), None
        for a in args:
            if a is not type(None):
                ok, v = _type_ok(value, a)
                if ok:
                    return True, v
        return False, value
    if tp is bool:
        return isinstance(value, bool), value
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool), value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False, value
        return math.isfinite(float(value)), float(value)
    if tp is str:
        return isinstance(value, str), value
    if origin is dict:
        key_tp, value_tp = typing.get_args(tp)
        if not isinstance(value, dict):
            return False, value
        checked = {k: _type_ok(v, value_tp) for k, v in value.items()}
        ok = all(_type_ok(k, key_tp)[0] for k in value) and all(ok for ok, _ in checked.values())
        return ok, {k: v for k, (_, v) in checked.items()}
    if origin is list:
        (item,) = typing.get_args(tp)
        if not isinstance(value, list):
            return False, value
        items = [_type_ok(v, item) for v in value]
        return all(ok for ok, _ in items), [v for _, v in items]
    return False, value


def _build(cls: type, data: Any, prefix: str, sections: dict[str, type] | None = None) -> Any:
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix}: expected a mapping, got {type(data).__name__}")
    data = dict(data)
    if cls is ModelConfig and "preset" in data:
        name = data.pop("preset")
        if name not in PRESETS:
            raise ConfigError(f"{prefix}.preset: unknown preset {name!r}; choose from {sorted(PRESETS)}")
        data = {**PRESETS[name], **data}
    hints = typing.get_type_hints(cls)
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        key = f"{prefix}.{unknown[0]}" if prefix else unknown[0]
        valid = sorted([*names, "preset"] if cls is ModelConfig else names)
        close = difflib.get_close_matches(unknown[0], valid, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ConfigError(f"{key}: unknown key ({hint}valid keys: {', '.join(valid)})")
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        section = names[name].metadata.get("section")  # a sub-section whose class is imported late
        tp = (sections or {}).get(name, section() if section is not None else hints[name])
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key)
            continue
        ok, coerced = _type_ok(value, tp)
        if not ok:
            raise ConfigError(f"{key}: expected {getattr(tp, '__name__', str(tp))}, got {value!r}")
        check = names[name].metadata.get("check")
        if coerced is not None and check is not None:
            problem = check(coerced)
            if problem:
                raise ConfigError(f"{key}: {problem}, got {value!r}")
        kwargs[name] = coerced
    for name, tp in (sections or {}).items():
        if name not in kwargs:
            kwargs[name] = _build(tp, {}, f"{prefix}.{name}" if prefix else name)
    obj = cls(**kwargs)
    if hasattr(obj, "validate"):
        obj.validate(prefix)
    return obj


def env_of(cfg: Config | ModelConfig) -> EnvConfig:
    """The env a checkpoint's model was trained on: a checkpoint with only a model config is the default
    humanoid's (the env of the first checkpoints, which saved no run config)."""
    return cfg.env if isinstance(cfg, Config) else EnvConfig()


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """Plain nested dict (YAML-serialisable) of a config dataclass."""
    return dataclasses.asdict(cfg)


def dump_config(cfg: Any) -> str:
    """YAML text of a config that `load_config` reads back to an equal object."""
    return yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
