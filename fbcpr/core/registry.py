"""The method registry: what `algorithm:` in a config (and in a checkpoint) names.

A method is a sub-package of `fbcpr` holding its model, losses and agent. The registry maps its name to
three classes, imported on first use so `import fbcpr.core.config` stays free of torch:
the `agent:` config section, the `OnlineAgent` the trainer drives, and the `nn.Module` a checkpoint holds.
Adding a method = a sub-package + one entry here.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fbcpr.core.config import ConfigError

if TYPE_CHECKING:
    import torch
    from torch import nn

    from fbcpr.core.config import Config, ModelConfig
    from fbcpr.envs.bundle import EnvBundle
    from fbcpr.core.protocols import ImitationReward, OnlineAgent

#: What a checkpoint that records no method holds (every checkpoint written before methods existed).
DEFAULT_ALGORITHM = "fb_cpr"


def _load(path: str) -> Any:
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Method:
    """Where one method's classes live ("module:Class"), and whether its model is prompt-able (a `BFM`)."""

    name: str
    config_path: str
    agent_path: str
    model_path: str
    promptable: bool

    def agent_config(self) -> type:
        return _load(self.config_path)

    def model(self, cfg: ModelConfig) -> nn.Module:
        """A fresh model of this method with the sizes of `cfg` (obs_dim and action_dim set)."""
        return _load(self.model_path)(cfg)

    def agent_class(self) -> type:
        """The agent's class, for what it declares before it exists (the replay fields it trains on: `fields`)."""
        return _load(self.agent_path)

    def agent(self, cfg: Config, bundle: EnvBundle, device: torch.device, seed: int) -> OnlineAgent:
        """The online agent for a run config on an environment."""
        return self.agent_class().from_config(cfg, bundle, device, seed)


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("fb_cpr", "fbcpr.core.config:AgentConfig", "fbcpr.methods.fb_cpr.agent:FBCPRAgent", "fbcpr.methods.fb_cpr.model:FBCPRModel", True),
    Method("td3", "fbcpr.methods.td3.config:TD3Config", "fbcpr.methods.td3.agent:TD3Agent", "fbcpr.methods.td3.model:TD3Model", False),
)}

#: Imitation rewards (`fbcpr.core.protocols.ImitationReward`) an RL agent can be trained on, by `reward.imitation` name.
IMITATION_REWARDS: dict[str, str] = {"amp": "fbcpr.rewards.amp.reward:AMPReward", "near": "fbcpr.rewards.near.reward:NEARReward",
                                     "virl": "fbcpr.rewards.virl.reward:VIRLReward",
                                     "progress": "fbcpr.rewards.progress:ProgressReward"}


def get_method(name: str) -> Method:
    """The registered method `name`; ConfigError naming `algorithm` otherwise."""
    if name not in METHODS:
        raise ConfigError(f"algorithm: unknown method {name!r}; choose from {sorted(METHODS)}")
    return METHODS[name]


def imitation_reward(name: str, obs_dim: int, agent_cfg: Any, device: torch.device, seed: int,
                     library: Any = None) -> ImitationReward:
    """A fresh imitation reward `name`, sized by the agent config's section of that name (`agent.amp`, ...), with
    the env's demonstration library (what NEAR pretrains on); ConfigError naming `agent.reward.imitation` for an
    unknown name."""
    if name not in IMITATION_REWARDS:
        raise ConfigError(f"agent.reward.imitation: unknown imitation reward {name!r}; choose from "
                          f"{sorted(IMITATION_REWARDS)}")
    return _load(IMITATION_REWARDS[name])(obs_dim, getattr(agent_cfg, name), device, seed, library=library)
