"""A continuation whose z draws include named reward prompts: `fbcpr train` with a share of nu's draws replaced.

    python lab/experiments/prompt_share_train.py lab/configs/cpu-getup-share.yaml --tasks move-ego-0-0 \
        --share 0.2 --init-from pretrained --out runs/cpu-getup-share

FB-CPR trains its actor and critics under z's drawn from nu (ER_FB of expert windows, B of online states, the
uniform sphere) for rollouts and for the batch rows it relabels. A reward prompt's z is none of those, so the
actor learns it only by generalisation: in section 60 (lab/log.md) the stand prompt, left free on fallen states,
still never rose. Here a share of every draw, rollouts and relabelled rows alike, is the z of a named reward task,
inferred once after the warm start through the frozen B from the loaded model's reward-inference sample, exactly
as the export infers the prompt it stores. Rollouts under the stand z from fall and focus starts, and actor and
critic updates under it on fallen batch states, are then what the get-up check asks of the model.
Lab only: the package's trainer is unchanged; this script swaps the fb_cpr agent for a subclass and runs the
train command. A resume would lose the inferred z's, so --resume is refused.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor

from fbcpr.core import registry
from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import TaskReward
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.methods.fb_cpr.anchor import reward_prompts


class PromptShareAgent(FBCPRAgent):
    """FBCPRAgent whose `sample_z` returns, with probability `share`, the z of one of the `tasks` (uniformly)."""

    tasks: ClassVar[tuple[str, ...]] = ()
    share: ClassVar[float] = 0.0

    def __init__(self, *args: Any, prompt_rewards: dict[str, TaskReward] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not self.cfg.freeze_backward:
            raise ConfigError("prompt_share_train: needs agent.freeze_backward: true (the shared z's are inferred "
                              "once through the loaded B, which must not move)")
        self.prompt_rewards = prompt_rewards or {}
        self.prompt_z: Tensor | None = None

    @classmethod
    def from_config(cls, cfg: Any, bundle: Any, device: torch.device, seed: int) -> PromptShareAgent:
        agent = super().from_config(cfg, bundle, device, seed)
        assert isinstance(agent, PromptShareAgent)
        agent.prompt_rewards = {t: bundle.task_reward(t) for t in cls.tasks}
        agent.notices.append(f"prompt share: {cls.share:.0%} of z draws are the prompts of {', '.join(cls.tasks)}")
        return agent

    @torch.no_grad()
    def warm_started(self, reward_sample: Callable[[], dict[str, np.ndarray] | None] | None = None) -> None:
        super().warm_started(reward_sample)
        sample = reward_sample() if reward_sample is not None else None
        if sample is None:
            raise ConfigError("prompt_share_train: the --init-from checkpoint has no reward-inference sample")
        self.prompt_z = reward_prompts(self.model, sample, self.prompt_rewards).to(self.device)

    def nu_draws(self, n: int, online_b: Tensor | None, expert_z: Tensor | None) -> dict[str, Tensor]:
        """nu's random numbers, and with them which draws take a prompt and whose: `sample_z` and `relabel`
        (which the update feeds pre-drawn numbers) both go through here and `mix_nu`."""
        draws = super().nu_draws(n, online_b, expert_z)
        if self.prompt_z is not None and self.share > 0.0:
            g, dev = self.generator, self.device
            draws["prompt_u"] = torch.rand(n, generator=g, device=dev)
            draws["prompt_idx"] = torch.randint(self.prompt_z.shape[0], (n,), generator=g, device=dev)
        return draws

    def mix_nu(self, draws: dict[str, Tensor], online_b: Tensor | None, expert_z: Tensor | None) -> Tensor:
        z = super().mix_nu(draws, online_b, expert_z)
        if self.prompt_z is None or "prompt_idx" not in draws:
            return z
        return torch.where((draws["prompt_u"] < self.share)[:, None], self.prompt_z[draws["prompt_idx"]], z)


def install(tasks: list[str], share: float) -> None:
    """Point the registry's fb_cpr method at PromptShareAgent with these tasks and share."""
    if not tasks:
        raise SystemExit("--tasks: name at least one reward task")
    if not 0.0 < share <= 1.0:
        raise SystemExit(f"--share: must be in (0, 1], got {share}")
    PromptShareAgent.tasks, PromptShareAgent.share = tuple(tasks), share
    registry.METHODS["fb_cpr"] = dataclasses.replace(registry.METHODS["fb_cpr"],
                                                     agent_path=f"{__name__}:PromptShareAgent")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", required=True, help="reward tasks whose prompts join the z draws")
    ap.add_argument("--share", type=float, default=0.2, help="probability that a draw is one of those prompts")
    args, rest = ap.parse_known_args()
    if "--resume" in rest:
        ap.error("--resume: the shared prompts are inferred at the warm start; start a new run with --init-from")
    if "--init-from" not in rest:
        ap.error("--init-from: the shared prompts are inferred from the loaded model's reward sample")
    install(args.tasks, args.share)
    from fbcpr.cli.app import app

    sys.argv = [sys.argv[0], "train", *rest]
    app()


if __name__ == "__main__":
    main()
