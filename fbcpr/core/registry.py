"""The plug-in registry: every method, imitation reward, env kind and offline model the package knows, by name.

Each entry names where its code lives ("module:attribute") and is imported on first use, so the layers below the
plug-ins never import them, and `import fbcpr.core.config` stays free of torch. Adding a plug-in = a sub-package
and one line here.
"""
from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from fbcpr.core.errors import ConfigError

if TYPE_CHECKING:
    import torch
    from torch import nn

    from fbcpr.core.protocols import EnvBundle, ImitationReward, OnlineAgent, OnlineAgentClass, StateObserver
    from fbcpr.core.schema import Config, EnvConfig, MethodConfig, ModelConfig

#: What a checkpoint that records no method holds (every checkpoint written before methods existed).
DEFAULT_ALGORITHM = "fb_cpr"


def load(path: str) -> Any:
    """The attribute a registry entry names ("module:attribute")."""
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Method:
    """Where one online method's classes live ("module:Class"), and whether its model is prompt-able (a `BFM`)."""

    name: str
    config_path: str
    agent_path: str
    model_path: str
    promptable: bool

    def agent_config(self) -> type[MethodConfig]:
        return load(self.config_path)

    def model(self, cfg: ModelConfig) -> nn.Module:
        """A fresh model of this method with the sizes of `cfg` (obs_dim and action_dim set)."""
        return load(self.model_path)(cfg)

    def agent_class(self) -> OnlineAgentClass:
        """The agent's class, for what it declares before it exists (the replay fields it trains on: `fields`)."""
        return load(self.agent_path)

    def agent(self, cfg: Config, bundle: EnvBundle, device: torch.device, seed: int) -> OnlineAgent:
        """The online agent for a run config on an environment."""
        return self.agent_class().from_config(cfg, bundle, device, seed)


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("fb_cpr", "fbcpr.methods.fb_cpr.config:AgentConfig", "fbcpr.methods.fb_cpr.agent:FBCPRAgent",
           "fbcpr.methods.fb_cpr.model:FBCPRModel", True),
    Method("td3", "fbcpr.methods.td3.config:TD3Section", "fbcpr.methods.td3.agent:TD3Agent",
           "fbcpr.methods.td3.model:TD3Model", False),
)}

@dataclass(frozen=True)
class Reward:
    """Where one imitation reward's class and its config section live ("module:Class")."""

    reward_path: str
    config_path: str


#: Imitation rewards (`fbcpr.core.protocols.ImitationReward`) an RL agent can be trained on, by
#: `agent.reward.imitation` name; each brings the agent config section of the same name (`agent.amp`, ...).
IMITATION_REWARDS: dict[str, Reward] = {
    "amp": Reward("fbcpr.rewards.amp.reward:AMPReward", "fbcpr.rewards.amp.config:AMPConfig"),
    "near": Reward("fbcpr.rewards.near.reward:NEARReward", "fbcpr.rewards.near.config:NEARConfig"),
    "virl": Reward("fbcpr.rewards.virl.reward:VIRLReward", "fbcpr.rewards.virl.config:VIRLConfig"),
    "progress": Reward("fbcpr.rewards.progress:ProgressReward", "fbcpr.rewards.progress:ProgressConfig"),
}


@dataclass(frozen=True)
class EnvKind:
    """An environment the trainer can run (`env.name`): its factory, (EnvConfig, num_envs, threads) -> EnvBundle,
    and its observation as a function of the state (reward samples stored as states only are rebuilt with it)."""

    make_path: str
    observer_path: str

    def make(self, cfg: EnvConfig, num_envs: int, threads: int | None) -> EnvBundle:
        return load(self.make_path)(cfg, num_envs, threads)

    def observer(self) -> StateObserver:
        return load(self.observer_path)()


ENVS: dict[str, EnvKind] = {
    "humanoid": EnvKind("fbcpr.envs.bundle:humanoid_bundle", "fbcpr.envs.bundle:humanoid_observer"),
    "toy": EnvKind("fbcpr.envs.toy:toy_bundle", "fbcpr.envs.toy:state_observer"),
}

#: `env.npmp`: (EnvBundle, EnvConfig) -> the bundle acting through an NPMP's latent space.
LATENT_ACTIONS = "fbcpr.apps.npmp.reuse:latent_bundle"

#: Offline models a checkpoint's manifest can record (`algorithm:`), each loaded as an evaluation agent by
#: (path, device, name) -> Agent: they track clips and are scored like a BFM, but are no online method.
OFFLINE_MODELS: dict[str, str] = {"npmp": "fbcpr.apps.npmp.agent:NPMPAgent"}


def get_method(name: str) -> Method:
    """The registered method `name`; ConfigError naming `algorithm` otherwise."""
    if name not in METHODS:
        raise ConfigError(f"algorithm: unknown method {name!r}; choose from {sorted(METHODS)}")
    return METHODS[name]


def env_kind(name: str) -> EnvKind:
    """The registered env `name`; ConfigError naming `env.name` otherwise."""
    if name not in ENVS:
        raise ConfigError(f"env.name: must be one of {sorted(ENVS)}, got {name!r}")
    return ENVS[name]


def imitation_reward(name: str, obs_dim: int, agent_cfg: Any, device: torch.device, seed: int,
                     library: Any = None) -> ImitationReward:
    """A fresh imitation reward `name`, sized by the agent config's section of that name (`agent.amp`, ...), with
    the env's demonstration library (what NEAR pretrains on); ConfigError naming `agent.reward.imitation` for an
    unknown name."""
    if name not in IMITATION_REWARDS:
        raise ConfigError(f"agent.reward.imitation: unknown imitation reward {name!r}; choose from "
                          f"{sorted(IMITATION_REWARDS)}")
    return load(IMITATION_REWARDS[name].reward_path)(obs_dim, getattr(agent_cfg, name), device, seed, library=library)


def with_imitation_sections(base: type[MethodConfig], name: str, doc: str) -> type[MethodConfig]:
    """`base` with one config section per registered imitation reward (`agent.amp`, `agent.near`, ...), each
    defaulting to that reward's own config: a method that trains on any imitation reward takes its sections from
    here, so a new reward needs only its registry line."""
    sections = [(key, load(r.config_path)) for key, r in IMITATION_REWARDS.items()]
    fields = [(key, cls, dataclasses.field(default_factory=cls, metadata={"check": None})) for key, cls in sections]
    return dataclasses.make_dataclass(name, fields, bases=(base,), namespace={"__doc__": doc})
