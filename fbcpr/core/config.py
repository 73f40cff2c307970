"""Typed run configuration: YAML maps onto nested dataclasses, validated field by field.

Unknown keys, wrong types and out-of-range values raise `ConfigError` naming the dotted key
(e.g. `agent.relabel_prob: must be in [0, 1], got 1.5`), so a typo never silently falls back to a default.
Defaults are the paper's values (App. C.5, Tables 3, 5-7, 9); `model.preset` picks a network size.
"""
from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import yaml

from fbcpr.core.errors import FBCPRError
from humanoid_env.actions import ACTION_MAPPINGS, DEFAULT_ACTION_MAPPING


class ConfigError(FBCPRError, ValueError):
    """A configuration value that is unknown, of the wrong type or out of range; the message names the key."""


def _check(pred: Callable[[Any], bool], what: str) -> Callable[[Any], str | None]:
    return lambda v: None if pred(v) else what


def _range(lo: float, hi: float) -> Callable[[Any], str | None]:
    """Bounds that keep a value within what one machine can run: a typo like 10**9 envs fails here, naming its
    key, not minutes later inside an allocation."""
    return _check(lambda v: lo <= v <= hi, f"must be in [{lo:,}, {hi:,}]")


POSITIVE = _check(lambda v: v > 0, "must be > 0")
NON_NEGATIVE = _check(lambda v: v >= 0, "must be >= 0")
PROB = _check(lambda v: 0.0 <= v <= 1.0, "must be in [0, 1]")


def _f(default: Any, check: Callable[[Any], str | None] | None = None, **kw: Any) -> Any:
    """A dataclass field with an optional validator stored in its metadata."""
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda d=default: type(d)(d), metadata={"check": check}, **kw)
    return field(default=default, metadata={"check": check}, **kw)


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


#: Sources of FB-CPR's policy-regularisation reward (`AgentConfig.regulariser`).
REGULARISERS = ("discriminator", "near")


def _near_config() -> type:
    """NEARConfig, imported late: fbcpr.rewards.near.config builds on this module's validators."""
    from fbcpr.rewards.near.config import NEARConfig

    return NEARConfig


@dataclass
class AgentConfig:
    """Learning hyperparameters of Algorithm 1 (Tables 3 and 9)."""

    batch_size: int = _f(1024, _range(2, 2**20))
    seq_length: int = _f(8, _range(1, 10_000))
    discount: float = _f(0.98, _check(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)"))
    lr_f: float = _f(1e-4, POSITIVE)
    lr_b: float = _f(1e-5, POSITIVE)
    lr_actor: float = _f(1e-4, POSITIVE)
    lr_critic: float = _f(1e-4, POSITIVE)
    lr_discriminator: float = _f(1e-5, POSITIVE)
    tau: float = _f(0.005, _check(lambda v: 0.0 < v <= 1.0, "must be in (0, 1]"))
    ortho_coef: float = _f(100.0, NON_NEGATIVE)
    fz_coef: float = _f(0.1, NON_NEGATIVE)
    actor_reg_coef: float = _f(0.01, NON_NEGATIVE)
    action_penalty: float = _f(0.0, NON_NEGATIVE)  # not in the paper: pull toward action 0 (`ensemble_td.action_penalty`)
    grad_penalty: float = _f(10.0, NON_NEGATIVE)
    # not in the paper, for runs continued with --init-from (`fbcpr.methods.fb_cpr.anchor`): hold B and the observation
    # normaliser at the loaded model's, so every prompt keeps its meaning; and pull the actor's mean on
    # demonstration states, under their own ER_FB latents, toward the loaded actor's (scaled like action_penalty)
    freeze_backward: bool = _f(False)
    anchor_actor: float = _f(0.0, NON_NEGATIVE)
    # reward tasks whose prompts the anchor holds as well: the batch's states under each task's z, inferred once
    # through the frozen B from the loaded model's reward-inference sample (needs freeze_backward and anchor_actor)
    anchor_rewards: list[str] = _f([])
    fb_pessimism: float = _f(0.0, NON_NEGATIVE)
    fz_pessimism: float = _f(0.5, NON_NEGATIVE)
    critic_pessimism: float = _f(0.5, NON_NEGATIVE)
    actor_pessimism: float = _f(0.5, NON_NEGATIVE)
    relabel_prob: float = _f(0.8, PROB)
    z_expert: float = _f(0.6, PROB)
    z_online: float = _f(0.2, PROB)
    z_uniform: float = _f(0.2, PROB)
    compile: bool = _f(False)
    # not in the paper: on CUDA, capture the whole update (losses, backward, Adam steps, Polyak) in one CUDA graph
    # and replay it, so ~300 kernels cost one launch (`fbcpr.nn.cuda_graph`); ignored on the CPU
    cuda_graph: bool = _f(False)
    bf16: bool | str = _f(False, _check(lambda v: isinstance(v, bool) or v == "auto", "must be true, false or 'auto'"))
    # not in the paper: what the critic's reward comes from, the discriminator's log-ratio or a z-conditioned NEAR
    # energy (`fbcpr.rewards.near.conditional`, configured by `near:`; experimental)
    regulariser: str = _f("discriminator", _check(lambda v: v in REGULARISERS, f"must be one of {REGULARISERS}"))
    near: Any = field(default_factory=lambda: _near_config()(), metadata={"check": None, "section": _near_config})

    def validate(self, prefix: str) -> None:
        total = self.z_expert + self.z_online + self.z_uniform
        if not math.isclose(total, 1.0, abs_tol=1e-6):
            raise ConfigError(f"{prefix}.z_expert + z_online + z_uniform: must sum to 1, got {total:g}")
        if self.anchor_rewards and not (self.freeze_backward and self.anchor_actor > 0):
            raise ConfigError(f"{prefix}.anchor_rewards: holds reward prompts inferred through a frozen B; needs "
                              f"{prefix}.freeze_backward: true and {prefix}.anchor_actor > 0")
        if len(set(self.anchor_rewards)) != len(self.anchor_rewards):
            raise ConfigError(f"{prefix}.anchor_rewards: a task is given twice in {self.anchor_rewards}")
        if self.cuda_graph and self.compile:
            raise ConfigError(f"{prefix}.cuda_graph: choose one of cuda_graph and compile (torch.compile cannot "
                              "differentiate the gradient penalty twice, and a graph already removes the launches)")
        if self.cuda_graph and self.regulariser != "discriminator":
            raise ConfigError(f"{prefix}.cuda_graph: needs regulariser: discriminator (the NEAR regulariser's "
                              f"annealing decides between updates on the CPU), got {self.regulariser!r}")


@dataclass
class EnvConfig:
    """Which environment and demonstrations; the trainer only sees what `fbcpr.envs.bundle.make_env` builds."""

    name: str = _f("humanoid", _check(lambda v: v in ("humanoid", "toy"), "must be 'humanoid' or 'toy'"))
    motions: str = _f("synthetic")  # humanoid: a folder of clips or one clip .npz; toy: "synthetic" (all demos) or demo names
    fall_prob: float = _f(0.2, PROB)
    stand_prob: float = _f(0.0, PROB)  # humanoid: share of training episodes that start from the standing rest pose
    # humanoid: share of training episodes that start on a frame of the clips named in focus_clips (reference-state
    # starts along a skill, e.g. [getup_facedown]: rising from half-way up is reachable by exploration)
    focus_prob: float = _f(0.0, PROB)
    focus_clips: list[str] = _f([])
    # humanoid: or draw those starts from the frames of other clips, a clip .npz or a folder of them, e.g. the sampling
    # planner's getting-up demonstrations (motions.demonstrations): states the body really passes through on a rise
    # that works, velocities included, where a mocap clip's frames are only kinematic
    focus_motions: str | None = _f(None)
    max_episode_steps: int = _f(300, _range(1, 10**7))
    action_mapping: str = _f(DEFAULT_ACTION_MAPPING, _check(lambda v: v in ACTION_MAPPINGS, f"must be one of {ACTION_MAPPINGS}"))
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
    npmp: str | None = _f(None)
    npmp_innovation_scale: float = _f(math.sqrt(3.0), POSITIVE)  # sqrt(3): uniform actions have unit variance


@dataclass
class TrainConfig:
    """Online loop (Tables 3, 4, 9): rollouts, update ratio, buffer, priorities, logging, checkpoints."""

    seed: int = _f(0, NON_NEGATIVE)
    device: str = _f("cpu", _check(lambda v: v == "cpu" or v.startswith("cuda") or v == "auto", "must be cpu, cuda[:i] or auto"))
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
    # stand comes and goes (lab/log.md section 24)
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
    # up, lab/experiments/getup_planner.py --save) whose transitions go into the replay buffer when a run starts (fresh or
    # --init-from), each demonstration_copies times: transitions that exploration has not found. As plain transitions
    # they made TD3's critic diverge in lab/log.md section 32
    demonstrations: str | None = _f(None)
    demonstration_copies: int = _f(1, _range(1, 1000))
    # > 0: the demonstrations are held apart from the replay buffer (never overwritten) and this share of every
    # update's batch is drawn from them, marked so that a loss can treat them apart (TD3's agent.bc_weight)
    demonstration_share: float = _f(0.0, _range(0.0, 0.5))
    torch_threads: int = _f(0, _range(0, 1024))
    # MuJoCo threads of the training envs; 0: all cores, split between the ranks of a torchrun on one machine.
    # Set it when other runs share the machine (several seeds on one leased GPU: lab/gpu)
    env_threads: int = _f(0, _range(0, 1024))
    dist_timeout_s: float = _f(600.0, _range(1.0, 86_400.0))  # torchrun runs: a rank gone this long is an error
    dist_backend: str = _f("auto", _check(lambda v: v in ("auto", "nccl", "gloo"), "must be auto, nccl or gloo"))


@dataclass
class Config:
    """A whole run: the method (`algorithm`), model sizes, its hyperparameters, environment and training loop.

    `agent` holds the named method's hyperparameters (`fbcpr.core.registry`): `AgentConfig` for FB-CPR."""

    algorithm: str = _f("fb_cpr")
    model: ModelConfig = field(default_factory=ModelConfig)
    agent: Any = field(default_factory=AgentConfig)
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
        checked = [_type_ok(v, item) for v in value]
        return all(ok for ok, _ in checked), [v for _, v in checked]
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
        raise ConfigError(f"{key}: unknown key (valid keys: {', '.join(sorted(names))})")
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        section = names[name].metadata.get("section")  # a sub-section whose class is imported late
        tp = (sections or {}).get(name, section() if section is not None else hints[name])
        if dataclasses.is_dataclass(tp):
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
    obj = cls(**kwargs)
    if hasattr(obj, "validate"):
        obj.validate(prefix)
    return obj


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a Config from plain data (as loaded from YAML); `algorithm` picks the `agent:` schema."""
    from fbcpr.core.registry import get_method

    algorithm = data.get("algorithm", Config.algorithm) if isinstance(data, dict) else Config.algorithm
    if not isinstance(algorithm, str):
        raise ConfigError(f"algorithm: expected str, got {algorithm!r}")
    cfg = _build(Config, data, "", sections={"agent": get_method(algorithm).agent_config()})
    if cfg.agent.batch_size % cfg.agent.seq_length:
        raise ConfigError(f"agent.batch_size: must be a multiple of agent.seq_length ({cfg.agent.seq_length}), "
                          f"got {cfg.agent.batch_size}")
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
    if getattr(cfg.agent, "bc_weight", 0.0) and not tc.demonstration_share:
        raise ConfigError("agent.bc_weight: clones the demonstrations' actions, so it needs train.demonstration_share > 0")
    if getattr(cfg.agent, "bootstrap_demo_actions", False) and not tc.demonstration_share:
        raise ConfigError("agent.bootstrap_demo_actions: reads the demonstrations' next actions, so it needs "
                          "train.demonstration_share > 0")
    if cfg.env.npmp is not None and (cfg.algorithm != "td3" or cfg.agent.reward.imitation):
        raise ConfigError("env.npmp: acting through an NPMP decoder needs a single-task method on a task reward "
                          "(algorithm td3 with agent.reward.imitation null): demonstrations have no latent actions")
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


#: Config keys that hold a file or folder path, for the envs where they do ("synthetic" names the built-in clips,
#: and the toy's env.motions names demonstrations, not paths); env None: every env. Sections may be dotted.
PATH_KEYS = (("env", "motions", "humanoid"), ("env", "focus_motions", "humanoid"), ("env", "npmp", None),
             ("agent.virl", "multitask", "humanoid"), ("agent.virl", "demo_frames", None),
             ("train", "demonstrations", "humanoid"))


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
        if not Path(value).expanduser().is_absolute():
            setattr(part, key, str((path.parent / value).resolve()))
    return cfg


def _paths(cfg: Config) -> list[tuple[Any, str, str]]:
    """(section object, key, value) of every path that `cfg` holds (PATH_KEYS that are set, for its env)."""
    out = []
    for section, key, env in PATH_KEYS:
        part = functools.reduce(lambda obj, name: getattr(obj, name, None), section.split("."), cfg)
        value = getattr(part, key, None)
        if value is not None and value != "synthetic" and env in (None, cfg.env.name):
            out.append((part, key, value))
    return out


def env_of(cfg: Config | ModelConfig) -> EnvConfig:
    """The env a checkpoint's model was trained on: a checkpoint with only a model config is the default
    humanoid's (the env of the first checkpoints, which saved no run config)."""
    return cfg.env if isinstance(cfg, Config) else EnvConfig()


def portable_config(cfg: Config, base: str | Path = ".") -> Config:
    """A copy whose paths under `base` are relative to it, so that a checkpoint made to be shared does not carry
    this machine's folders (paths elsewhere stay as they are: they were never portable)."""
    import copy

    out = copy.deepcopy(cfg)
    root = Path(base).resolve()
    for part, key, value in _paths(out):
        target = Path(value).expanduser()
        if target.is_absolute() and target.is_relative_to(root):
            setattr(part, key, target.relative_to(root).as_posix())
    return out


def shipped_configs() -> dict[str, Path]:
    """The configs that ship inside the package (fbcpr.configs), by name."""
    from importlib import resources

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


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """Plain nested dict (YAML-serialisable) of a config dataclass."""
    return dataclasses.asdict(cfg)


def dump_config(cfg: Any) -> str:
    """YAML text of a config that `load_config` reads back to an equal object."""
    return yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
