"""FB-CPR's `agent:` section: the learning hyperparameters of Algorithm 1 (Tables 3 and 9)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import NON_NEGATIVE, POSITIVE, PROB, Config, MethodConfig, _check, _f, _range, check_windows
from fbcpr.rewards.near.config import NEARConfig

#: Sources of FB-CPR's policy-regularisation reward (`AgentConfig.regulariser`).
REGULARISERS = ("discriminator", "near")


@dataclass
class AgentConfig(MethodConfig):
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
    # not in the paper: pull toward action 0 (`ensemble_td.action_penalty`)
    action_penalty: float = _f(0.0, NON_NEGATIVE)
    grad_penalty: float = _f(10.0, NON_NEGATIVE)
    # not in the paper, for runs continued with --init-from (`fbcpr.methods.fb_cpr.anchor`): hold B and the observation
    # normaliser at the loaded model's, so every prompt keeps its meaning; and pull the actor's mean on
    # demonstration states, under their own ER_FB latents, toward the loaded actor's (scaled like action_penalty)
    freeze_backward: bool = _f(False)
    anchor_actor: float = _f(0.0, NON_NEGATIVE)
    # reward tasks whose prompts the anchor holds as well: the batch's states under each task's z, the loaded model's
    # stored prompt where it has one, else inferred once through the frozen B from its reward-inference sample
    # (needs freeze_backward and anchor_actor)
    anchor_rewards: list[str] = _f([])
    # clips (shell-style patterns on clip names) whose windows the anchor leaves free: a new skill's demonstrations,
    # which a continued run is to learn rather than hold at the loaded actor (needs anchor_actor)
    anchor_free: list[str] = _f([])
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
    near: NEARConfig = field(default_factory=NEARConfig, metadata={"check": None, "section": lambda: NEARConfig})

    def validate(self, prefix: str) -> None:
        total = self.z_expert + self.z_online + self.z_uniform
        if not math.isclose(total, 1.0, abs_tol=1e-6):
            raise ConfigError(f"{prefix}.z_expert + z_online + z_uniform: must sum to 1, got {total:g}")
        if self.anchor_rewards and not (self.freeze_backward and self.anchor_actor > 0):
            raise ConfigError(f"{prefix}.anchor_rewards: holds reward prompts inferred through a frozen B; needs "
                              f"{prefix}.freeze_backward: true and {prefix}.anchor_actor > 0")
        if self.anchor_free and not self.anchor_actor > 0:
            raise ConfigError(f"{prefix}.anchor_free: names clips that the actor anchor leaves free; needs "
                              f"{prefix}.anchor_actor > 0")
        if len(set(self.anchor_rewards)) != len(self.anchor_rewards):
            raise ConfigError(f"{prefix}.anchor_rewards: a task is given twice in {self.anchor_rewards}")
        if self.cuda_graph and self.compile:
            raise ConfigError(f"{prefix}.cuda_graph: choose one of cuda_graph and compile (torch.compile cannot "
                              "differentiate the gradient penalty twice, and a graph already removes the launches)")
        if self.cuda_graph and self.regulariser != "discriminator":
            raise ConfigError(f"{prefix}.cuda_graph: needs regulariser: discriminator (the NEAR regulariser's "
                              f"annealing decides between updates on the CPU), got {self.regulariser!r}")

    def validate_run(self, run: Config) -> None:
        check_windows(self.batch_size, self.seq_length)
        if run.env.npmp is not None:
            raise ConfigError("env.npmp: acting through an NPMP decoder needs a single-task method on a task reward "
                              "(algorithm td3 with agent.reward.imitation null): demonstrations have no latent actions")

    def holds_loaded_model(self) -> list[str]:
        return [f"agent.{key}" for key in ("freeze_backward", "anchor_actor") if getattr(self, key)]
