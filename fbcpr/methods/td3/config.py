"""The `agent:` section of `algorithm: td3` (Table 8): its hyperparameters, its reward sources, and one section per
registered imitation reward (`TD3Section`, built from the registry)."""
from __future__ import annotations

from dataclasses import dataclass, field

from fbcpr.core.errors import ConfigError
from fbcpr.core.registry import with_imitation_sections
from fbcpr.core.schema import NON_NEGATIVE, POSITIVE, Config, MethodConfig, _check, _f, check_windows


@dataclass
class RewardConfig:
    """The reward TD3 maximises: task_weight * task(s') + imitation_weight * imitation(s, s') (NEAR Eq. 3 style).

    `task` names a reward of the env's registry (humanoid_env.tasks, or the toy's tasks); `imitation` names an
    `fbcpr.core.registry.IMITATION_REWARDS` entry learned from the env's demonstrations. Either may be null."""

    task: str | None = _f(None)
    task_weight: float = _f(1.0, NON_NEGATIVE)
    imitation: str | None = _f(None)
    imitation_weight: float = _f(1.0, NON_NEGATIVE)

    def validate(self, prefix: str) -> None:
        if not (self.task and self.task_weight > 0) and not (self.imitation and self.imitation_weight > 0):
            raise ConfigError(f"{prefix}: give a task, an imitation reward, or both, with a weight > 0")


@dataclass
class TD3Config(MethodConfig):
    """TD3 hyperparameters (Table 8): critic and actor rates, Polyak tau, ensemble penalties (0: the mean)."""

    batch_size: int = _f(1024, _check(lambda v: v >= 2, "must be >= 2"))
    seq_length: int = _f(8, _check(lambda v: v >= 2, "must be >= 2"))  # demo windows: L - 1 expert transitions each
    discount: float = _f(0.98, _check(lambda v: 0.0 <= v < 1.0, "must be in [0, 1)"))
    lr_actor: float = _f(1e-4, POSITIVE)
    lr_critic: float = _f(1e-4, POSITIVE)
    tau: float = _f(0.005, _check(lambda v: 0.0 < v <= 1.0, "must be in (0, 1]"))
    critic_pessimism: float = _f(0.0, NON_NEGATIVE)
    actor_pessimism: float = _f(0.0, NON_NEGATIVE)
    # not in the paper: pull toward action 0 (`ensemble_td.action_penalty`)
    action_penalty: float = _f(0.0, NON_NEGATIVE)
    # TD3+BC (Fujimoto & Gu, 2021) on the batch's demonstration rows (train.demonstration_share): the squared error
    # to their actions, scaled like action_penalty by the mean |Q|, so the policy's actions where it bootstraps on
    # demonstrated states stay near those the critic was trained on (alone it slowed the critic's divergence on
    # demonstration rows but did not stop it)
    bc_weight: float = _f(0.0, NON_NEGATIVE)
    # the TD target of a demonstration row bootstraps on the demonstrator's next action, not the policy's: a critic
    # that only saw demonstrated actions there overrates the policy's nearby ones, and its target carried that gap
    # back along every demonstration, times 1 / (1 - discount)
    bootstrap_demo_actions: bool = _f(False)
    bf16: bool | str = _f(False, _check(lambda v: isinstance(v, bool) or v == "auto", "must be true, false or 'auto'"))
    reward: RewardConfig = field(default_factory=RewardConfig)

    def validate_run(self, run: Config) -> None:
        check_windows(self.batch_size, self.seq_length)
        share = run.train.demonstration_share
        if self.bc_weight and not share:
            raise ConfigError("agent.bc_weight: clones the demonstrations' actions, so it needs "
                              "train.demonstration_share > 0")
        if self.bootstrap_demo_actions and not share:
            raise ConfigError("agent.bootstrap_demo_actions: reads the demonstrations' next actions, so it needs "
                              "train.demonstration_share > 0")
        if run.env.npmp is not None and self.reward.imitation:
            raise ConfigError("env.npmp: acting through an NPMP decoder needs a single-task method on a task reward "
                              "(algorithm td3 with agent.reward.imitation null): demonstrations have no latent actions")


#: The section `algorithm: td3` reads: TD3Config plus `agent.<name>` for each imitation reward of the registry.
TD3Section = with_imitation_sections(TD3Config, "TD3Section", TD3Config.__doc__ or "")
