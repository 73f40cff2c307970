"""The seams between a method, an environment and the rest of the package.

`EnvBundle` is all that the trainer and an agent know of an environment (built by `fbcpr.envs`).

`OnlineAgent` is what the one online trainer (`fbcpr.train.trainer.Trainer`) drives, whatever the method:

    rollouts   z = agent.rollout_z(n, online_next_obs, expert_windows)  # (n, z_dim); z_dim = 0: no latent
               a = agent.act(obs, z)                                    # exploration actions in [-1, 1]
    learning   metrics = agent.update(buffer.sample(fields=agent.fields), expert_windows)
    checkpoint agent.model (-> model.safetensors), agent.state() / load_state() (-> trainer_state.safetensors)
    optional   agent.observe(obs, next_obs, z) # each batch of online transitions as collected, with the rollout
                                               # latents (NEAR's annealing)
               agent.window_clips: bool        # True: each batch carries batch["window_clip"], the library index
                                               # of each expert window's clip (FB-CPR's `agent.anchor_free`)
               agent.notices: list[str]        # lines shown once when training starts

`ImitationReward` is a reward learned from demonstrations that plugs into any RL agent: `fit` on expert
transitions (and, for adversarial rewards, the agent's own), then a batched `reward(obs, next_obs[, z])`. It is
built by `fbcpr.core.registry.imitation_reward` with the env's demonstration library, which a reward trained offline
before RL (NEAR) pretrains on in its first `fit`.
A sequence reward (VIRL) also has an int attribute `history` > 0: the agent then samples each transition with the
`history` states of its episode before s (`ReplayBuffer.sample(history=)`, batch["history"]) and passes them as
`reward(obs, next_obs, history=...)`. A video reward on the humanoid also has `frame_size` > 0: the collector
renders each s' once as a grey uint8 frame of that side, the replay buffer keeps it, and the agent passes the frames
of history + s' as `reward(..., frames=(n, history + 1, size, size))` and in `fit`'s batch["frames"].
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor, nn

if TYPE_CHECKING:
    from fbcpr.core.schema import Config

#: A registry reward on next states: (next_obs (N, obs_dim), qpos (N, nq), qvel (N, nv)) -> (N,).
TaskReward = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]



@dataclass
class EnvBundle:
    """What the trainer, agents and evaluations see of an environment, whichever it is (`fbcpr.envs` builds it)."""

    env: Any                                              # gymnasium VectorEnv, SAME_STEP autoreset, with
    # get_state() -> (qpos, qvel, episode steps), and save_state() -> dict of arrays / load_state(dict) -> obs: its
    # whole state, which a resumed run restores to step bit for bit as the saved one would have
    library: Any                                          # demonstrations (MotionLibrary-like)
    obs_dim: int
    action_dim: int
    nq: int
    nv: int
    make_eval_env: Callable[[int, int], Any]              # (num_envs, max_episode_steps) -> VectorEnv
    clip_obs: Callable[[int], np.ndarray]                 # clip index -> (T, obs_dim) reference observations
    clip_start: Callable[[int], tuple[np.ndarray, np.ndarray]]  # clip index -> (qpos, qvel) of frame 0
    emd: Callable[[np.ndarray, np.ndarray], float]        # tracking EMD between two (T, obs_dim) trajectories
    success: Callable[[np.ndarray, np.ndarray], bool]     # tracking success (time-aligned)
    task_reward: Callable[[str], TaskReward]              # registry task name -> reward of (next_obs, qpos, qvel)


#: Observations of states: (qpos (N, nq), qvel (N, nv)) -> next_obs (N, obs_dim) float32.
StateObserver = Callable[[np.ndarray, np.ndarray], np.ndarray]


@runtime_checkable
class OnlineAgent(Protocol):
    """A learner the online trainer can drive (FB-CPR's `FBCPRAgent`, `TD3Agent`, ...)."""

    model: nn.Module              # what inference needs; saved as model.safetensors, rebuilt by `fbcpr.core.registry`
    generator: torch.Generator    # the agent's own random stream (saved with its state)
    fields: tuple[str, ...]       # replay-buffer fields `update` reads
    z_dim: int                    # width of the latent stored with each transition (0: not latent-conditioned)

    def rollout_z(self, n: int, online_next_obs: Tensor | None, expert_windows: Tensor) -> Tensor:
        """n latents for rollouts, from raw online next states (None while the buffer is empty) and demo windows."""
        ...

    def act(self, obs: Tensor, z: Tensor) -> Tensor:
        """Exploration actions (N, action_dim) in [-1, 1] for raw observations and rollout latents."""
        ...

    def update(self, batch: dict[str, Tensor], expert_windows: Tensor) -> Mapping[str, float]:
        """One learning step from a replay batch and raw demonstration windows (w, L, obs_dim); returns metrics
        (a `fbcpr.nn.lazy_metrics.LazyMetrics`, so that the step does not wait for the device)."""
        ...

    def warm_started(self, reward_sample: Callable[[], dict[str, np.ndarray] | None] | None = None,
                     stored_prompts: Callable[[], dict[str, np.ndarray] | None] | None = None) -> None:
        """Called once after a warm start loaded another run's weights into `model`: every target network := its
        online network, and whatever else the agent derives from the loaded model. `reward_sample()` reads the
        loaded checkpoint's reward-inference sample (None where it has none), and `stored_prompts()` its stored reward
        prompts by task (checked against its weights; None where it has none), for an agent that needs them."""
        ...

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """(tensors, JSON metadata) beyond `model` needed to continue exactly."""
        ...

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        ...


class OnlineAgentClass(Protocol):
    """An online agent's class, as the registry loads it: what it declares before it exists (the replay fields it
    trains on) and how a run builds it."""

    fields: tuple[str, ...]

    def from_config(self, cfg: Config, bundle: EnvBundle, device: torch.device, seed: int) -> OnlineAgent:
        """The agent for a run config on an environment (a classmethod of the agent class)."""
        ...


@runtime_checkable
class BF16Agent(Protocol):
    """An agent whose update can run under bf16 autocast (`agent.bf16`); the trainer settles "auto" on it."""

    bf16: bool


@runtime_checkable
class GraphedAgent(Protocol):
    """An agent whose update can be captured in a CUDA graph (`agent.cuda_graph`): `graphed` says whether it is."""

    graphed: bool


@runtime_checkable
class ImitationReward(Protocol):
    """A reward learned from demonstrations (AMP's D(s, s'), FB-CPR's D(s, z); NEAR's energy, VIRL's comparator)."""

    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """One fitting step on raw expert windows (w, L, obs_dim) and an online replay batch; returns metrics."""
        ...

    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> Tensor:
        """(N,) rewards for raw transitions (s, s') (and latents, for latent-conditioned rewards), without gradient."""
        ...

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        ...

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        ...
