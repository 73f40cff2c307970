"""FBCPRAgent: one gradient step of Algorithm 1 on every network, plus target nets and z sampling.

All losses are computed from the same pre-update parameters (as in the pseudocode, lines 14-33) and
summed into one backward pass. Forward passes that several losses use are computed once:
B(s') feeds the FB loss, the orthonormality loss, Sigma_B and the online-goal relabeling; the (s, z)
embeddings of F and Q feed both their TD losses and the actor loss; the actor's next action and the
target nets feed both TD targets; expert and online states go through the discriminator in one batch.
The actor loss evaluates F and Q with detached weights, so one backward leaves them untouched by it.
With `agent.regulariser: near` a z-conditioned energy (`fbcpr.rewards.near.conditional`) takes the discriminator's
place: its DSM loss joins the one backward and its anchored energy is the critic's reward.
A continued run can hold B and the normaliser fixed (`agent.freeze_backward`) and anchor the actor on demonstration
states (`agent.anchor_actor`, `fbcpr.methods.fb_cpr.anchor`) but those of a new skill's clips (`agent.anchor_free`),
and on the batch's states under named reward prompts (`agent.anchor_rewards`).
On CUDA, `agent.cuda_graph` captures the whole step (`_train_step`) in one CUDA graph and replays it.
"""
from __future__ import annotations

import contextlib
import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import TaskReward
from fbcpr.core.schema import Config, ModelConfig
from fbcpr.methods.fb_cpr import losses
from fbcpr.methods.fb_cpr.anchor import ActorAnchor, free_clips, reward_prompts
from fbcpr.methods.fb_cpr.config import AgentConfig
from fbcpr.methods.fb_cpr.imitation import discriminator_terms, encode_windows, penalty_pairs
from fbcpr.methods.fb_cpr.model import FBCPRModel
from fbcpr.nn import distributed
from fbcpr.nn.bf16_weights import BF16Weights
from fbcpr.nn.cuda_graph import GraphedStep
from fbcpr.nn.lazy_metrics import LazyMetrics
from fbcpr.nn.networks import project_sphere
from fbcpr.nn.optim_state import fused_adam, load_optimizer_state, optimizer_state
from fbcpr.nn.precision import resolve_bf16
from fbcpr.rewards.near.conditional import ConditionalEnergy

#: Modules with a Polyak-averaged target copy.
TARGETS = ("forward_map", "backward_map", "critic")
#: Optimised modules and the AgentConfig field holding each learning rate.
OPTIMISED = {"forward_map": "lr_f", "backward_map": "lr_b", "actor": "lr_actor", "critic": "lr_critic",
             "discriminator": "lr_discriminator"}


class FBCPRAgent:
    """Model + target networks + Adam optimisers + the update of Algorithm 1 (an `fbcpr.core.protocols.OnlineAgent`)."""

    fields = ("obs", "action", "next_obs", "z", "terminated")
    #: the model's modules that acting and rollout latents read (`act`, `rollout_z`): all a collector process needs
    acting_modules = ("obs_normalizer", "actor", "backward_map")

    def __init__(self, model_cfg: ModelConfig, agent_cfg: AgentConfig, device: str | torch.device = "cpu",
                 seed: int = 0, task_reward: Callable[[str], TaskReward] | None = None,
                 free: np.ndarray | None = None) -> None:
        """task_reward: the env's reward of a task name (`EnvBundle.task_reward`), for `agent.anchor_rewards`;
        free: (clips,) bool, the motion library's clips whose windows the anchor leaves free (`agent.anchor_free`)."""
        self.cfg = agent_cfg
        self.device = torch.device(device)
        self.bf16 = resolve_bf16(agent_cfg.bf16, self.device)
        torch.manual_seed(seed)
        self.model = FBCPRModel(model_cfg).to(self.device)
        self.targets = nn.ModuleDict({k: copy.deepcopy(getattr(self.model, k)) for k in TARGETS})
        self.targets.requires_grad_(False)
        trained = {k: (getattr(self.model, k), getattr(agent_cfg, lr)) for k, lr in OPTIMISED.items()}
        if agent_cfg.freeze_backward:
            del trained["backward_map"]
            self.model.backward_map.requires_grad_(False)
        # the actor of the model a continued run starts from, and its reward prompts (`warm_started` takes them; a
        # resume loads them)
        if agent_cfg.anchor_rewards and task_reward is None:
            raise ConfigError("agent.anchor_rewards: the agent needs the env's task rewards (task_reward) to infer "
                              "the held reward prompts")
        self.held_rewards = {k: task_reward(k) for k in agent_cfg.anchor_rewards} if task_reward else {}
        self.anchor = ActorAnchor(self.model, len(self.held_rewards)) if agent_cfg.anchor_actor > 0 else None
        if agent_cfg.anchor_free and free is None:
            raise ConfigError("agent.anchor_free: the agent needs the motion library's clips (free) to leave them free")
        self.free = None if free is None else torch.as_tensor(free, dtype=torch.bool, device=self.device)
        self.window_clips = self.free is not None  # the trainer then marks each window's clip ("window_clip")
        self.notices: list[str] = []  # lines the trainer shows once at the start
        self._bf16: BF16Weights | None = None  # the bf16 weight copies of `agent.bf16` (`_bf16_copies`)
        # the NEAR regulariser, which replaces the discriminator's training
        self.energy: ConditionalEnergy | None = None
        if agent_cfg.regulariser == "near":
            assert model_cfg.obs_dim is not None  # FBCPRModel above refuses a config without it
            self.energy = ConditionalEnergy(model_cfg.obs_dim, model_cfg.z_dim, agent_cfg.near).to(self.device)
            del trained["discriminator"]
            trained["energy"] = (self.energy.energy, agent_cfg.near.lr)
        # a captured update steps Adam on the device (`fbcpr.nn.cuda_graph`)
        self.graphed = agent_cfg.cuda_graph and self.device.type == "cuda"
        self.optimizers = {k: fused_adam(m.parameters(), lr, capturable=self.graphed) for k, (m, lr) in trained.items()}
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed)
        self.num_updates = 0
        # torch.compile cannot differentiate twice, so the gradient penalty always runs eagerly
        self._gradient_penalty = (torch.compiler.disable(losses.gradient_penalty) if agent_cfg.compile
                                  else losses.gradient_penalty)
        if self.energy is not None:  # DSM differentiates twice as well
            self._expert_energy = (torch.compiler.disable(self.energy.expert_terms) if agent_cfg.compile
                                   else self.energy.expert_terms)
        self._compute = torch.compile(self._losses) if agent_cfg.compile else self._losses
        self._step = GraphedStep(self._train_step, self.device, [self.generator]) if self.graphed else self._train_step

    @classmethod
    def from_config(cls, cfg: Config, bundle: Any, device: torch.device, seed: int) -> FBCPRAgent:
        agent_cfg = cfg.agent
        assert isinstance(agent_cfg, AgentConfig)  # what a config of algorithm fb_cpr reads its agent section as
        free = free_clips(bundle.library, agent_cfg.anchor_free) if agent_cfg.anchor_free else None
        agent = cls(cfg.model, agent_cfg, device, seed,
                    task_reward=bundle.task_reward if agent_cfg.anchor_rewards else None, free=free)
        if free is not None:
            names = [n for n, f in zip(bundle.library.names, free) if f]
            agent.notices.append(f"agent.anchor_free: the anchor leaves {len(names)} of {len(free)} clips free: "
                                 f"{', '.join(names[:8])}{' ...' if len(names) > 8 else ''}")
        return agent

    @property
    def z_dim(self) -> int:
        return self.model.cfg.z_dim

    # ------------------------------------------------------------------------------------- rollouts
    @torch.no_grad()
    def rollout_z(self, n: int, online_next_obs: Tensor | None, expert_windows: Tensor) -> Tensor:
        """n draws from nu for rollouts: B of online states, ER_FB of demonstration windows, uniform."""
        model = self.model
        online_b = None
        if online_next_obs is not None:
            online_b = model.backward_map(model.normalize(online_next_obs.to(self.device)))
        expert_z = self.encode_windows(model.normalize(expert_windows.to(self.device)))
        return self.sample_z(n, online_b, expert_z)

    def act(self, obs: Tensor, z: Tensor) -> Tensor:
        """The policy's exploration actions (clipped Gaussian noise around the tanh mean)."""
        return self.model.act(obs, z, mean=False, generator=self.generator)

    @torch.no_grad()
    def observe(self, obs: Tensor, next_obs: Tensor, z: Tensor) -> None:
        """Online transitions as collected with their rollout latents: the NEAR regulariser's annealing buffer
        (from the first update on; the discriminator needs nothing)."""
        if self.energy is not None and self.num_updates > 0:
            obs, next_obs = obs.to(self.device, torch.float32), next_obs.to(self.device, torch.float32)
            self.energy.observe(self.model.normalize(obs), next_obs - obs, z.to(self.device))

    # ------------------------------------------------------------------------------------- z sampling
    def sample_z(self, n: int, online_b: Tensor | None, expert_z: Tensor | None) -> Tensor:
        """n draws from nu: ER_FB of expert windows (z_expert), B of online states (z_online), uniform sphere.

        A component whose source is missing (no online states yet, no demonstrations) gives way to uniform."""
        return self.mix_nu(self.nu_draws(n, online_b, expert_z), online_b, expert_z)

    def nu_draws(self, n: int, online_b: Tensor | None, expert_z: Tensor | None) -> dict[str, Tensor]:
        """The random numbers of n draws from nu (`mix_nu`), from the agent's generator: a component, a uniform
        latent, and an index into each source given (only its size is read)."""
        g, dev = self.generator, self.device
        draws = {"u": torch.rand(n, generator=g, device=dev),
                 "uniform": torch.randn(n, self.model.cfg.z_dim, generator=g, device=dev)}
        if expert_z is not None:
            draws["expert_idx"] = torch.randint(expert_z.shape[0], (n,), generator=g, device=dev)
        if online_b is not None:
            draws["online_idx"] = torch.randint(online_b.shape[0], (n,), generator=g, device=dev)
        return draws

    def mix_nu(self, draws: dict[str, Tensor], online_b: Tensor | None, expert_z: Tensor | None) -> Tensor:
        """Draws from nu made of `nu_draws`' random numbers."""
        p_expert = self.cfg.z_expert if expert_z is not None else 0.0
        p_online = self.cfg.z_online if online_b is not None else 0.0
        u = draws["u"]
        z = project_sphere(draws["uniform"])
        if expert_z is not None:
            z = torch.where((u < p_expert)[:, None], expert_z[draws["expert_idx"]], z)
        if online_b is not None:
            z = torch.where(((u >= p_expert) & (u < p_expert + p_online))[:, None], online_b[draws["online_idx"]], z)
        return z

    def relabel(self, z: Tensor, online_b: Tensor, expert_z: Tensor | None,
                draws: dict[str, Tensor] | None = None) -> Tensor:
        """Replace each z with probability relabel_prob by a fresh draw from nu (lines 17-18).

        online_b are B values of online states (here B(s') of the batch, already computed); draws: the update's
        random numbers (`_draws`), else drawn here."""
        if draws is None:
            draws = self.nu_draws(z.shape[0], online_b, expert_z)
            draws["keep"] = torch.rand(z.shape[0], generator=self.generator, device=self.device)
        keep = draws["keep"] >= self.cfg.relabel_prob
        return torch.where(keep[:, None], z, self.mix_nu(draws, online_b, expert_z))

    def encode_windows(self, windows_n: Tensor) -> Tensor:
        """ER_FB of normalized windows (w, L, obs) -> (w, d) (`fbcpr.methods.fb_cpr.imitation.encode_windows`)."""
        return encode_windows(self.model, windows_n)

    # ------------------------------------------------------------------------------------- update
    def update(self, batch: dict[str, Tensor], expert_windows: Tensor) -> LazyMetrics:
        """One gradient step on all networks. batch: obs, action, next_obs, z, terminated (n rows);
        expert_windows: (n / seq_length, seq_length, obs_dim) raw observations from the motion data. The metrics
        stay on the device until read (`fbcpr.nn.lazy_metrics`)."""
        if self.graphed and distributed.active() is not None:
            raise ConfigError("agent.cuda_graph: not under torchrun (the ranks average gradients between backward and "
                              "step, outside any graph); set agent.cuda_graph: false")
        out = self._step(self._inputs(batch, expert_windows))
        self.num_updates += 1
        extra = None
        if self.energy is not None:  # NEAR's annealing reads its energy every update (never graphed)
            self.energy.step_ema()
            extra = self.energy.end_phase(float(out["energy_expert"]))
        return LazyMetrics(out, extra)

    def backward(self, batch: dict[str, Tensor], expert_windows: Tensor) -> dict[str, Tensor]:
        """The update's losses on one batch, with their gradients left in every optimised network and no step
        taken: what `update` applies, and what benchmarks/bf16_agreement.py compares between precisions."""
        return self._backward(self._inputs(batch, expert_windows))

    def _inputs(self, batch: dict[str, Tensor], expert_windows: Tensor) -> dict[str, Tensor]:
        """The update's inputs as float32 tensors on the device (a captured update reads copies of these)."""
        dev = self.device
        inputs = {k: batch[k].to(dev, torch.float32) for k in ("obs", "action", "next_obs", "z")}
        inputs["terminated"] = batch["terminated"].to(dev, torch.float32).reshape(-1)
        inputs["expert"] = expert_windows.to(dev, torch.float32)
        if self.free is None:
            inputs["expert_held"] = torch.ones(expert_windows.shape[0], device=dev)
        else:
            if "window_clip" not in batch:
                raise ValueError("FBCPRAgent.update: agent.anchor_free needs each window's clip in the batch "
                                 "(\"window_clip\"), as the trainer samples it")
            inputs["expert_held"] = (~self.free[batch["window_clip"].to(dev)]).float()
        return inputs

    def _train_step(self, inputs: dict[str, Tensor]) -> dict[str, Tensor]:
        """Backward, every optimiser's step and Polyak: the part of an update that a CUDA graph captures. Returns
        the metrics as float32 scalars on the device."""
        out = self._backward(inputs)
        for opt in self.optimizers.values():
            opt.step()
        self.soft_update()
        return {k: v.detach().float() for k, v in out.items()}

    def _backward(self, inputs: dict[str, Tensor]) -> dict[str, Tensor]:
        obs, expert = inputs["obs"], inputs["expert"]
        expert_flat = expert.reshape(-1, expert.shape[-1])
        if not self.cfg.freeze_backward:  # B reads normalised states: a frozen B needs frozen statistics
            self.model.obs_normalizer.update(torch.cat([obs, expert_flat]))
        if self.energy is not None:
            self.energy.step_normalizer.update(expert[:, 1:] - expert[:, :-1])
        copies = self._bf16_copies()
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.bf16), \
                copies.swapped() if copies is not None else contextlib.nullcontext():
            out = self._compute(inputs["obs"], inputs["action"], inputs["next_obs"], inputs["z"], inputs["terminated"],
                                inputs["expert"], inputs["expert_held"], self._draws(inputs["obs"], inputs["expert"]))
        total = out.pop("_total")
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        total.backward()
        if copies is not None:
            copies.gradients_to_masters()
        if self.energy is not None:
            torch.nn.utils.clip_grad_norm_(self.energy.energy.parameters(), self.cfg.near.grad_clip)
        return out

    def _bf16_copies(self) -> BF16Weights | None:
        """Under `agent.bf16`, the ensemble layers' bf16 weight copies, refreshed for this step (made on first use:
        benchmarks/bf16_agreement.py switches `bf16` on an agent it built)."""
        if not self.bf16:
            return None
        if self._bf16 is None:
            model, tg = self.model, self.targets  # B runs in float32 (`fbcpr.nn.networks.BackwardNet`)
            self._bf16 = BF16Weights([model.forward_map, model.actor, model.critic, model.discriminator,
                                      tg["forward_map"], tg["critic"]])
        self._bf16.refresh()
        return self._bf16

    def _draws(self, obs: Tensor, expert: Tensor) -> dict[str, Tensor]:
        """The update's random numbers, drawn from the agent's generator in the order the loss computation uses
        them, before it runs: a compiled `_losses` then traces no generator, which would split it at every draw.
        mix: the gradient penalty's interpolation weights; u, uniform, expert_idx, online_idx, keep: the relabeling's
        draws from nu (`nu_draws`); noise_next, noise_pi: the actor's noise at s' and s; task: the anchor's reward
        prompt of each state."""
        g, dev, n = self.generator, self.device, obs.shape[0]
        action_dim = self.model.cfg.action_dim
        assert action_dim is not None  # FBCPRModel refuses a config without it
        draws = {}
        if self.energy is None:
            draws["mix"] = torch.rand(penalty_pairs(expert, obs), generator=g, device=dev)
        draws.update(self.nu_draws(n, obs, expert))  # z from windows' and B(s') latents: w and n of them
        draws["keep"] = torch.rand(n, generator=g, device=dev)
        for k in ("noise_next", "noise_pi"):
            draws[k] = torch.randn(n, action_dim, generator=g, device=dev)
        if self.anchor is not None and self.anchor.prompts is not None:
            draws["task"] = torch.randint(self.anchor.prompts.shape[0], (n,), generator=g, device=dev)
        return draws

    def _losses(self, obs: Tensor, action: Tensor, next_obs: Tensor, z_buf: Tensor, terminated: Tensor,
                expert: Tensor, expert_held: Tensor | None = None,
                draws: dict[str, Tensor] | None = None) -> dict[str, Tensor]:
        """expert_held: (w,) 1 for the windows the actor anchor holds, 0 for those it leaves free (all held when
        None); draws: the update's random numbers (`_draws`; drawn here when None)."""
        cfg, model, tg = self.cfg, self.model, self.targets
        draws = self._draws(obs, expert) if draws is None else draws
        w, L = expert.shape[:2]
        obs_n, next_n = model.normalize(obs), model.normalize(next_obs)
        expert_n = model.normalize(expert)
        discount = cfg.discount * (1.0 - terminated)

        # discriminator: expert (s, ER_FB(window)) vs online (s, z) in one forward, plus WGAN-GP;
        # or the NEAR regulariser: DSM on expert (s, s' - s | ER_FB(window)) and the anchor of its reward
        z_exp = self.encode_windows(expert_n)
        if self.energy is None:
            logits, disc, gp = discriminator_terms(model.discriminator, expert_n, z_exp, obs_n, z_buf, draws["mix"],
                                                   self._gradient_penalty)
            regulariser = disc + cfg.grad_penalty * gp
            reg_metrics = {"disc_loss": disc, "grad_penalty": gp, "disc_expert": torch.sigmoid(logits[: w * L]).mean(),
                           "disc_online": torch.sigmoid(logits[w * L:]).mean()}
        else:
            regulariser, anchor = self._expert_energy(expert_n, expert, z_exp, self.generator)
            reg_metrics = {"dsm_loss": regulariser, "energy_expert": anchor}

        # B(s') once: FB loss, ortho loss, Sigma_B, online-goal relabeling
        B_next = model.backward_map(next_n)
        B_det = B_next.detach()
        z = self.relabel(z_buf, B_det, z_exp, draws)

        with torch.no_grad():
            a_next = model.actor_sample(next_n, z, noise=draws["noise_next"])
            F_next = tg["forward_map"](next_n, a_next, z)                       # (m, n, d)
            target_M = losses.pessimistic(torch.einsum("mid,jd->mij", F_next, tg["backward_map"](next_n)),
                                          cfg.fb_pessimism)
            target_Fz = losses.pessimistic((F_next * z).sum(-1), cfg.fz_pessimism)
            target_Q = losses.pessimistic(tg["critic"](next_n, a_next, z)[..., 0], cfg.critic_pessimism)
            if self.energy is None:
                reward = model.discriminator.logits(obs_n, z)                   # log D - log(1 - D)
            else:
                reward = self.energy.reward(obs_n, next_obs - obs, z, anchor)    # e(s, s' - s | z) / sigma_k
            r_fz = losses.implicit_reward(B_det, z)

        # F: FB TD loss + Fz regularisation; Q: TD on the discriminator reward
        pre_F = model.forward_map.precompute(obs_n, z)
        F_sa = model.forward_map(obs_n, action, z, pre=pre_F)
        M = torch.einsum("mid,jd->mij", F_sa, B_next)
        fb = losses.fb_loss(M, target_M, discount)
        fz = losses.td_loss((F_sa * z).sum(-1), r_fz, target_Fz, discount)
        ortho = losses.ortho_loss(B_next)
        pre_Q = model.critic.precompute(obs_n, z)
        Q_sa = model.critic(obs_n, action, z, pre=pre_Q)[..., 0]
        critic = losses.td_loss(Q_sa, reward, target_Q, discount)

        # actor: F and Q with frozen weights at a ~ pi(s, z), reusing their (s, z)-only parts
        a_pi = model.actor_sample(obs_n, z, noise=draws["noise_pi"])
        detached = lambda pre: tuple(t.detach() for t in pre)  # noqa: E731
        Fz_pi = (model.forward_map(obs_n, a_pi, z, detach_params=True, pre=detached(pre_F)) * z).sum(-1)
        Q_pi = model.critic(obs_n, a_pi, z, detach_params=True, pre=detached(pre_Q))[..., 0]
        anchor_metrics, gap = {}, None
        if self.anchor is not None:  # the actor's mean on demonstration states under their own ER_FB latents
            gap = self.anchor.gap(model, expert.reshape(w * L, -1), expert_n.reshape(w * L, -1),
                                  z_exp.detach().repeat_interleave(L, 0),
                                  None if expert_held is None else expert_held.repeat_interleave(L, 0))
            anchor_metrics = {"anchor_gap": gap}
            if self.anchor.prompts is not None:  # and on the batch's states, each under a held reward prompt
                reward_gap = self.anchor.gap(model, obs, obs_n, self.anchor.prompts[draws["task"]])
                anchor_metrics["anchor_gap_rewards"] = reward_gap
                gap = gap + reward_gap
        actor = losses.actor_loss(Fz_pi, Q_pi, cfg.actor_reg_coef, cfg.actor_pessimism, a_pi, cfg.action_penalty,
                                  gap, cfg.anchor_actor)

        total = (regulariser + fb + cfg.fz_coef * fz + cfg.ortho_coef * ortho + critic + actor)
        return {
            "_total": total, "fb_loss": fb, "fz_loss": fz, "ortho_loss": ortho, "critic_loss": critic,
            "actor_loss": actor, "reward": reward.mean(),
            "q": Q_sa.mean(), "fz": Fz_pi.mean(), "M_diag": torch.diagonal(M, dim1=-2, dim2=-1).mean(), **reg_metrics,
            **anchor_metrics,
        }

    @torch.no_grad()
    def warm_started(self, reward_sample: Callable[[], dict[str, np.ndarray] | None] | None = None,
                     stored_prompts: Callable[[], dict[str, np.ndarray] | None] | None = None) -> None:
        """After a warm start loaded weights into `model`: every target network := its online network, the actor
        anchor (if any) := the loaded actor, and each held reward prompt := the loaded model's stored prompt for
        that task where it stores one (the z its `prompt --reward` plays, refined at export or not), else the z the
        loaded B infers from the loaded model's reward-inference sample (`reward_sample()` and `stored_prompts()`
        read them)."""
        for k in TARGETS:
            self.targets[k].load_state_dict(getattr(self.model, k).state_dict())
        if self.anchor is not None:
            self.anchor.hold(self.model)
        if not self.held_rewards:
            return
        loaded = stored_prompts() if stored_prompts is not None else None
        stored = {k: v for k, v in (loaded or {}).items() if k in self.held_rewards}
        infer = {k: fn for k, fn in self.held_rewards.items() if k not in stored}
        inferred: dict[str, Tensor] = {}
        if infer:
            sample = reward_sample() if reward_sample is not None else None
            if sample is None:
                raise ConfigError("agent.anchor_rewards: the --init-from checkpoint has no reward-inference sample, "
                                  f"so there are no reward prompts to hold for {', '.join(infer)}")
            inferred = dict(zip(infer, reward_prompts(self.model, sample, infer)))
        # anchor_rewards needs anchor_actor (the config checks it), and the anchor then holds a prompt per task
        assert self.anchor is not None and self.anchor.prompts is not None
        prompts = self.anchor.prompts
        for i, name in enumerate(self.held_rewards):
            prompts[i] = torch.as_tensor(stored[name], dtype=prompts.dtype) if name in stored else inferred[name]
        if stored:
            rest = ", the rest at the z's its B infers" if infer else ""
            self.notices.append(f"agent.anchor_rewards: {len(stored)} of {len(self.held_rewards)} held at the loaded "
                                f"model's stored prompts ({', '.join(stored)}){rest}")

    @torch.no_grad()
    def soft_update(self) -> None:
        """Polyak averaging target <- (1 - tau) target + tau online, one fused op over all tensors."""
        tgt: list[Tensor] = [p for k in TARGETS for p in self.targets[k].parameters()]
        src: list[Tensor] = [p for k in TARGETS for p in getattr(self.model, k).parameters()]
        torch._foreach_lerp_(tgt, src, self.cfg.tau)

    # ------------------------------------------------------------------------------------- state
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """Everything beyond the model needed to continue exactly: targets, optimisers, generator."""
        tensors: dict[str, Tensor] = {f"target.{k}": v for k, v in self.targets.state_dict().items()}
        meta: dict[str, Any] = {"num_updates": self.num_updates, "optimizers": {}}
        for name, opt in self.optimizers.items():
            meta["optimizers"][name] = optimizer_state(opt, f"optim.{name}", tensors)
        tensors["agent_generator"] = self.generator.get_state()
        if self.energy is not None:
            tensors.update({f"near.{k}": v for k, v in self.energy.state_dict().items()})
            meta["near"] = self.energy.meta()
        if self.anchor is not None:
            tensors.update({f"anchor.{k}": v for k, v in self.anchor.state_dict().items()})
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        from fbcpr.core.checkpoint import CheckpointError, load_state_strict

        targets = {k[len("target."):]: v for k, v in tensors.items() if k.startswith("target.")}
        load_state_strict(self.targets, targets, "trainer_state.safetensors (target networks)")
        self.targets.to(self.device)
        if self.energy is not None:
            near = {k[len("near."):]: v for k, v in tensors.items() if k.startswith("near.")}
            load_state_strict(self.energy, near, "trainer_state.safetensors (NEAR regulariser)")
            if "near" not in meta:
                raise CheckpointError("trainer_state.safetensors: no NEAR regulariser state (agent.regulariser: near)")
            self.energy.load_meta(meta["near"])
        if self.anchor is not None:
            anchor = {k[len("anchor."):]: v for k, v in tensors.items() if k.startswith("anchor.")}
            load_state_strict(self.anchor, anchor, "trainer_state.safetensors (actor anchor, agent.anchor_actor)")
            self.anchor.to(self.device)
        try:
            for name, opt in self.optimizers.items():
                load_optimizer_state(opt, f"optim.{name}", meta["optimizers"][name], tensors)
            self.generator.set_state(tensors["agent_generator"])
            self.num_updates = int(meta["num_updates"])
        except (KeyError, ValueError, RuntimeError) as e:
            raise CheckpointError(f"trainer_state.safetensors: optimizer/generator state does not match "
                                  f"({e})") from None
