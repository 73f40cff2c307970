"""TD3Agent: the paper's single-task TD3 (App. C.5.2) on one reward, as an `fbcpr.core.protocols.OnlineAgent`.

The reward of a replay transition is relabelled at update time, like FB-CPR's: a registry task evaluated on the
stored next state (qpos, qvel, next_obs), an imitation reward on (s, s') (fitted one step per update first), or
their weighted sum. The critic ensemble's TD target and the actor loss use the same pessimistic reduction as
FB-CPR (`fbcpr.nn.ensemble_td`); exploration and target smoothing the same clipped noise (`noisy_action`).
"""
from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor

from fbcpr.core.protocols import ImitationReward, TaskReward
from fbcpr.core.schema import Config, ModelConfig
from fbcpr.methods.td3.config import TD3Config
from fbcpr.methods.td3.model import TD3Model
from fbcpr.nn.ensemble_td import action_penalty, behaviour_cloning, pessimistic, td_loss
from fbcpr.nn.lazy_metrics import LazyMetrics
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state
from fbcpr.nn.precision import resolve_bf16


class TD3Agent:
    """Actor, critic ensemble and its Polyak target, Adam optimisers, and a reward (task, imitation or both)."""

    fields = ("obs", "action", "next_obs", "qpos", "qvel", "terminated")
    z_dim = 0

    def __init__(self, model_cfg: ModelConfig, agent_cfg: TD3Config, device: str | torch.device = "cpu", seed: int = 0,
                 task_reward: TaskReward | None = None, imitation: ImitationReward | None = None) -> None:
        self.cfg = agent_cfg
        self.device = torch.device(device)
        self.bf16 = resolve_bf16(agent_cfg.bf16, self.device)
        torch.manual_seed(seed)
        self.model = TD3Model(model_cfg).to(self.device)
        self.target_critic = copy.deepcopy(self.model.critic).requires_grad_(False)
        self.optimizers = {"actor": torch.optim.Adam(self.model.actor.parameters(), lr=agent_cfg.lr_actor),
                           "critic": torch.optim.Adam(self.model.critic.parameters(), lr=agent_cfg.lr_critic)}
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed)
        self.task_reward, self.imitation = task_reward, imitation
        # states before s the trainer samples with each transition for a sequence reward (VIRL); 0: none
        self.history: int = getattr(imitation, "history", 0)
        # side of the grey frame of each s' the collector renders for a video reward (VIRL on the humanoid); 0: none
        self.frame_size: int = getattr(imitation, "frame_size", 0)
        self.num_updates = 0

    @classmethod
    def from_config(cls, cfg: Config, bundle: Any, device: torch.device, seed: int) -> TD3Agent:
        """TD3 on `agent.reward`: the env's registry task and/or an imitation reward of its demonstrations."""
        from fbcpr.core.registry import imitation_reward

        agent_cfg = cfg.agent
        assert isinstance(agent_cfg, TD3Config)  # what a config of algorithm td3 reads its agent section as
        rc = agent_cfg.reward
        rc.validate("agent.reward")
        task = bundle.task_reward(rc.task) if rc.task else None
        imitation = (imitation_reward(rc.imitation, bundle.obs_dim, agent_cfg, device, seed, bundle.library)
                     if rc.imitation else None)
        return cls(cfg.model, agent_cfg, device, seed, task_reward=task, imitation=imitation)

    # ------------------------------------------------------------------------------------- acting
    def rollout_z(self, n: int, online_next_obs: Tensor | None, expert_windows: Tensor) -> Tensor:
        """No latent: an empty (n, 0) z."""
        return torch.zeros(n, 0, device=self.device)

    def act(self, obs: Tensor, z: Tensor) -> Tensor:
        """Exploration actions: the deterministic policy plus clipped Gaussian noise."""
        with torch.no_grad():
            return self.model.actor_sample(self.model.normalize(obs.to(self.device)), self.generator)

    def observe(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None) -> None:
        """Online transitions as they are collected, for an imitation reward that tracks the agent's progress
        (NEAR's annealing); the replay batches `update` gets are too old for that. z (no latent here) is unused."""
        watch = getattr(self.imitation, "observe", None)
        if watch is not None:
            watch(obs.to(self.device), next_obs.to(self.device))

    # ------------------------------------------------------------------------------------- reward
    def reward(self, batch: dict[str, Tensor]) -> Tensor:
        """task_weight * task(s') + imitation_weight * imitation(s, s') of raw replay transitions, (n,)."""
        rc, total = self.cfg.reward, None
        if self.task_reward is not None:
            task_r = self.task_reward(*(batch[k].cpu().numpy() for k in ("next_obs", "qpos", "qvel")))
            total = rc.task_weight * torch.as_tensor(np.asarray(task_r), dtype=torch.float32, device=self.device)
        if self.imitation is not None:
            seq = {"history": batch["history"]} if self.history else {}
            if self.frame_size:
                seq["frames"] = batch["frames"]
            r = rc.imitation_weight * self.imitation.reward(batch["obs"].to(self.device),
                                                            batch["next_obs"].to(self.device), **seq)
            total = r if total is None else total + r
        assert total is not None, "agent.reward was validated to name a source"
        return total

    # ------------------------------------------------------------------------------------- update
    def update(self, batch: dict[str, Tensor], expert_windows: Tensor) -> LazyMetrics:
        """One critic and actor step (plus one imitation-reward fitting step when there is one); the metrics stay
        on the device until read."""
        cfg, model, dev = self.cfg, self.model, self.device
        metrics = self.imitation.fit(expert_windows, batch) if self.imitation is not None else {}
        reward = self.reward(batch)
        obs, action, next_obs = (batch[k].to(dev, torch.float32) for k in ("obs", "action", "next_obs"))
        discount = cfg.discount * (1.0 - batch["terminated"].to(dev, torch.float32).reshape(-1))
        model.obs_normalizer.update(obs)
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=self.bf16):
            obs_n, next_n = model.normalize(obs), model.normalize(next_obs)
            with torch.no_grad():
                a_next = model.actor_sample(next_n, self.generator)
                if cfg.bootstrap_demo_actions:  # the trainer marks the demonstration rows that go on
                    a_next = torch.where(batch["demo_next"].to(dev)[:, None],
                                         batch["demo_next_action"].to(dev, a_next.dtype), a_next)
                q_next = self.target_critic(torch.cat([next_n, a_next], -1))[..., 0]
                target = pessimistic(q_next, cfg.critic_pessimism)
            q = model.q(obs_n, action)
            critic = td_loss(q, reward, target, discount)
            a_pi = model.actor_mean(obs_n)
            q_pi = pessimistic(model.q(obs_n, a_pi, detach_params=True), cfg.actor_pessimism)
            actor = -q_pi.mean() + action_penalty(a_pi, q_pi.abs().mean(), cfg.action_penalty)
            bc = None
            if cfg.bc_weight:  # the trainer marks the demonstration rows (train.demonstration_share)
                bc = behaviour_cloning(a_pi, batch["demo_target"].to(dev, a_pi.dtype),
                                       batch["demo"].to(dev, torch.float32), q_pi.abs().mean(), cfg.bc_weight)
                actor = actor + bc
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        (critic + actor).backward()
        for opt in self.optimizers.values():
            opt.step()
        with torch.no_grad():
            torch._foreach_lerp_(list(self.target_critic.parameters()), list(model.critic.parameters()), cfg.tau)
        self.num_updates += 1
        values = {"critic_loss": critic, "actor_loss": actor, "reward": reward.mean(), "q": q.detach().float().mean()}
        if bc is not None:
            values["bc_loss"] = bc
        return LazyMetrics(values, metrics)

    @torch.no_grad()
    def warm_started(self, reward_sample: Callable[[], dict[str, np.ndarray] | None] | None = None,
                     stored_prompts: Callable[[], dict[str, np.ndarray] | None] | None = None) -> None:
        self.target_critic.load_state_dict(self.model.critic.state_dict())

    # ------------------------------------------------------------------------------------- state
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """Target critic, optimiser moments, generator, and the imitation reward's own state."""
        tensors: dict[str, Tensor] = {f"target.critic.{k}": v for k, v in self.target_critic.state_dict().items()}
        meta: dict[str, Any] = {"num_updates": self.num_updates, "optimizers": {}}
        for name, opt in self.optimizers.items():
            meta["optimizers"][name] = optimizer_state(opt, f"optim.{name}", tensors)
        tensors["agent_generator"] = self.generator.get_state()
        if self.imitation is not None:
            t, m = self.imitation.state()
            tensors.update({f"imitation.{k}": v for k, v in t.items()})
            meta["imitation"] = m
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        from fbcpr.core.checkpoint import CheckpointError, load_state_strict

        target = {k[len("target.critic."):]: v for k, v in tensors.items() if k.startswith("target.critic.")}
        load_state_strict(self.target_critic, target, "trainer_state.safetensors (target critic)")
        try:
            for name, opt in self.optimizers.items():
                load_optimizer_state(opt, f"optim.{name}", meta["optimizers"][name], tensors)
            self.generator.set_state(tensors["agent_generator"])
            self.num_updates = int(meta["num_updates"])
            if self.imitation is not None:
                self.imitation.load_state({k[len("imitation."):]: v for k, v in tensors.items()
                                           if k.startswith("imitation.")}, meta["imitation"])
        except (KeyError, ValueError, RuntimeError) as e:
            raise CheckpointError(f"trainer_state.safetensors: optimizer/generator state does not match "
                                  f"({e})") from None
