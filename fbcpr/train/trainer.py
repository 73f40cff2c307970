"""Online training loop of every method (Algorithm 1 with the protocol of App. C.5.1 for FB-CPR): the run's bookkeeping.

Each iteration has the collector (`fbcpr.train.collector`, or with `train.engine: async` the collector processes of
`fbcpr.train.workers`) add `rollout_steps` transitions from `num_envs` parallel envs (random actions during warm-up,
then the policy with z ~ nu resampled every `z_update_every` steps), then has the learner (`fbcpr.train.learner`) run
`updates_per_rollout` gradient steps. The trainer keeps the schedule, evaluations, checkpoints and logs. The
agent is the config's `algorithm` (`fbcpr.core.registry`), driven through `fbcpr.core.protocols.OnlineAgent`; z is its
rollout latent (empty for single-task agents). Every `priority_every` env steps the policy tracks the clips and the
motion priorities are reset from the tracking EMD (1/|bin| scheme of App. C.4). Checkpoints carry the model, the exact
learner state (target nets, optimisers, normaliser, counters, RNG states, env states and optionally the replay buffer)
and a reward-inference subsample of the buffer. SIGINT/SIGTERM ends the run at the next safe point with a final
checkpoint. Under torchrun every rank runs this loop on its own envs and replay shard with a replica of the learner,
kept identical by `fbcpr.nn.distributed` (gradients averaged over ranks, normaliser statistics merged); step counts and
periods are global, and only rank 0 writes. Optional packages degrade with one warning each: without tensorboard metrics
go to metrics.csv only; without any EMD solver (POT, or scipy for the equal-length fallback) tracking evaluation and the
priority refresh are skipped.
"""
from __future__ import annotations

import csv
import functools
import json
import math
import os
import random
import shutil
import signal
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from rich.console import Console
from rich.progress import Progress

from fbcpr.core.checkpoint import (
    MANIFEST_FILE,
    REPLAY_FILE,
    CheckpointError,
    discard_checkpoint,
    inconsistent_rows,
    latest_checkpoint,
    load_checkpoint,
    load_state_strict,
    prunable_checkpoints,
    read_manifest,
    read_trainer_meta,
    remove_stale_temporaries,
    save_checkpoint,
    write_pointer,
)
from fbcpr.core.errors import ConfigError
from fbcpr.core.protocols import BF16Agent, EnvBundle, GraphedAgent, OnlineAgent
from fbcpr.core.registry import get_method
from fbcpr.core.schema import BatchConfig, Config, batch_config
from fbcpr.envs.bundle import make_env
from fbcpr.eval.tracking import tracking_scores
from fbcpr.metrics import EMDUnavailable
from fbcpr.nn import distributed
from fbcpr.train.buffer import FRAME, ReplayBuffer, transition_specs
from fbcpr.train.collector import Collector
from fbcpr.train.device_batches import DeviceBatches
from fbcpr.train.learner import Learner
from fbcpr.train.reporting import progress_columns, summary_writer
from fbcpr.train.resources import check_memory, check_model_memory
from fbcpr.train.schedule import check_world_size, phase_steps, rescheduled
from fbcpr.train.workers import STOP_SIGNALS, CollectorPool

LIVE_KEYS = ("fb_loss", "actor_loss", "critic_loss", "disc_loss", "reward")
#: Failure signatures reported by public FB-CPR users, checked at every log row: (name, test, message).
WARNINGS: tuple[tuple[str, Callable[[dict[str, float]], bool], str], ...] = (
    ("discriminator", lambda m: m.get("disc_expert", 0.0) > 0.95 and m.get("disc_online", 1.0) < 0.05,
     "the discriminator separates expert from online states almost perfectly: the imitation reward is a constant "
     "penalty and the actor learns little from it (a signature of runs that end lying on the ground)"),
    ("bang-bang", lambda m: m.get("action_saturated", 0.0) > 0.5,
     "over half of the policy's action components sit beyond 0.9: a bang-bang actor, which falls "
     "(agent.action_penalty pulls the policy toward action 0)"),
    ("non-finite", lambda m: m.get("buffer_dropped", 0) > 0,
     "transitions with NaN or inf values reached the replay buffer and were dropped (see buffer_dropped)"),
)




def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"train.device: {name} requested but CUDA is not available")
    return torch.device(name)


class Trainer:
    """Owns env, agent, buffer and logs of one run directory (`out_dir`)."""

    def __init__(self, cfg: Config, out_dir: str | Path, resume: bool = False,
                 evaluate: Callable[[OnlineAgent], dict[str, float]] | None = None, progress: bool = True,
                 init_from: str | Path | None = None) -> None:
        self.out = Path(out_dir)
        self.custom_eval = evaluate
        tc = cfg.train
        if tc.torch_threads:
            torch.set_num_threads(tc.torch_threads)
        # device and env fail before the run directory exists; a world size that does not fit fails before the
        # process group starts, so every rank exits at once with the same one-line error
        check_world_size(cfg, distributed.launched_world_size())
        self.replicas, self.device = distributed.setup(resolve_device(tc.device), tc.dist_timeout_s, tc.dist_backend)
        r = self.replicas
        # the live bar only on a terminal: in a log it would print its last state once, metrics cut to its width,
        # so a log gets the plain line every train.log_every env steps instead
        self.progress_enabled = progress and r.is_main and Console(stderr=True).is_terminal
        check_world_size(cfg, r.world_size)
        if r.enabled and r.is_main:  # say what runs: N processes training one model, not N copies of one run
            plan = distributed.run_plan(r, tc.num_envs, batch_config(cfg.agent).batch_size, tc.updates_per_rollout,
                                        tc.num_envs * r.world_size * phase_steps(tc, r.world_size))
            Console(stderr=True).print(plan, highlight=False, soft_wrap=True)
        r.check_replicated({"config": torch.frombuffer(bytearray(config_json(cfg).encode()), dtype=torch.uint8)},
                           "the run config")
        seed = tc.seed + r.rank  # this rank's envs and random streams (rank 0: those of a single process)
        # ranks on one machine share its cores for physics (one process: all of them, as MuJoCo's default)
        threads = tc.env_threads or (max(1, (os.cpu_count() or 1) // r.local_world_size)
                                     if r.local_world_size > 1 else None)
        if tc.engine == "async":
            check_async(cfg, r.world_size)
        # async: the envs step in the collectors, and this process's env only gives evaluations their spaces
        self.bundle: EnvBundle = make_env(cfg.env, 1 if tc.engine == "async" else tc.num_envs, seed, threads)
        b = self.bundle
        for key, have in (("obs_dim", b.obs_dim), ("action_dim", b.action_dim)):
            given = getattr(cfg.model, key)
            if given is not None and given != have:
                raise ConfigError(f"model.{key}: {given} does not match the {cfg.env.name} env ({have})")
        self.cfg = cfg = replace(cfg, model=replace(cfg.model, obs_dim=b.obs_dim, action_dim=b.action_dim))
        if batch_config(cfg.agent).batch_size > tc.buffer_capacity:
            raise ConfigError("train.buffer_capacity: must be >= agent.batch_size")
        model_memory = check_model_memory(cfg, self.device, copies=r.local_world_size)  # before the agent is made

        random.seed(seed)
        np.random.seed(seed)
        self.rng = np.random.default_rng(seed)
        torch.manual_seed(tc.seed)  # parts an agent initialises before seeding (an imitation reward's network) included
        self.agent = get_method(cfg.algorithm).agent(cfg, b, self.device, tc.seed)  # the same weights on every rank
        if r.enabled:
            torch.manual_seed(seed)
            self.agent.generator.manual_seed(seed)
        if init_from is None and not resume:
            _check_fresh(cfg)
        # the loaded model's reward-inference sample, which every checkpoint carries as it is (train.keep_reward_sample)
        self._kept_sample: dict[str, np.ndarray] | None = None
        # a warm start's reader of that sample, for train.eval_at_start: prompts at step 0, and is let go after it
        self._loaded_sample: Callable[[], dict[str, np.ndarray] | None] | None = None
        self.warm_started = init_from is not None and not resume
        if self.warm_started and init_from is not None:
            self._warm_start(init_from)
        specs = transition_specs(b.obs_dim, b.action_dim, self.agent.z_dim, b.nq, b.nv)
        frame_size = getattr(self.agent, "frame_size", 0)  # a video reward: each s' rendered once, kept as a frame
        if frame_size:
            if tc.engine == "async":
                raise ConfigError("train.engine: async workers do not render the frames this agent's video reward "
                                  "reads; use sync")
            specs[FRAME] = (frame_size, frame_size)
        self._memmap_buffer = check_memory(cfg, specs, model_memory, self.out, self.device, copies=r.local_world_size)
        self.out.mkdir(parents=True, exist_ok=True)
        if r.is_main and (self.out / "checkpoints").is_dir():
            remove_stale_temporaries(self.out / "checkpoints")
        mmap = self.out / ("buffer_mmap" if r.is_main else f"buffer_mmap_rank{r.rank}")
        self.buffer = ReplayBuffer(tc.buffer_capacity, specs, mmap if self._memmap_buffer else None, stride=tc.num_envs)
        self.batches: DeviceBatches | None = None  # train.device_buffer: update batches drawn on the device
        if tc.device_buffer:
            if getattr(self.agent, "history", 0):
                raise ConfigError("train.device_buffer: this agent's reward reads the states before each transition "
                                  "(a sequence reward), which only the host buffer gives; set it to false")
            self.batches = DeviceBatches(self.buffer, b.library, self.agent.fields, self.device,
                                         seed=int(np.random.SeedSequence((seed, 1)).generate_state(1)[0]))

        self.env_steps = 0
        self.learner = Learner(cfg, self.agent, b, self.buffer, self.batches, self.rng, r)
        self._announce_speed_switches()
        for line in getattr(self.agent, "notices", ()):
            self._notice(line)
        self.next_priority = tc.priority_every or math.inf
        self.next_eval = 0 if tc.eval_at_start and tc.eval_every else (tc.eval_every or math.inf)
        self.next_ckpt = tc.checkpoint_every or math.inf
        self.next_log = 0
        self.emd: dict[str, float] = {}
        self._warned: set[str] = set()
        self._stop = False
        self._agreed_stop = False  # under torchrun: the stop decision every rank took together at the last phase end
        self._deadline = math.inf  # time.monotonic() at which run() stops (its `deadline`)
        self._saved_at: int | None = None  # env steps of the checkpoint on disk (none yet)
        self._wall_before = 0.0  # seconds of training before this run() call, summed over the run's resumes
        self._run_t0: float | None = None  # time.perf_counter() at the start of the run() call in progress
        # train.keep_best (rank 0): the best value of the metric so far and the checkpoint folder it was measured at
        self.best: tuple[float, str] | None = None
        # reward-inference sample carried over a resume without the replay buffer, and how many transitions it stands
        # for
        self._carried: dict[str, np.ndarray] | None = None
        self._carried_weight = 0
        self._updates_from = tc.warmup_steps  # env steps before the first update (later after a buffer-less resume)
        self._last_line = 0.0
        self.collector: Collector | CollectorPool = (
            CollectorPool(cfg, b, self.agent, self.buffer, self.batches, self.rng, self.device, os.cpu_count() or 1)
            if tc.engine == "async" else Collector(cfg, b, self.agent, self.buffer, self.batches, self.rng,
                                                   self.device, seed))
        if tc.demonstrations and (not resume or tc.demonstration_share):  # a resume finds copies in its saved buffer
            self._add_demonstrations(Path(tc.demonstrations), tc.demonstration_copies)
        if resume:
            self._resume()
        if not self.warm_started:  # a run from scratch explores at random until the warm-up's global env steps
            self.collector.random_steps = max(0, math.ceil((tc.warmup_steps - self.env_steps)
                                                           / (tc.num_envs * r.world_size)))
        if r.enabled:
            r.check_replicated(self._learner_state(*self.agent.state()), "the learner state")
        self.csv_path = self.out / "metrics.csv"
        self._writer: Any = None  # SummaryWriter once created, False where tensorboard is missing

    def _announce_speed_switches(self) -> None:
        """Say what the speed switches chose on this machine: bf16 "auto" is timed here (and agreed by the ranks),
        and a CUDA graph does nothing off CUDA."""
        agent, cfg = self.agent, self.cfg
        if getattr(cfg.agent, "bf16", False) == "auto":
            assert isinstance(agent, BF16Agent)  # a method with a bf16 switch has the attribute
            agent.bf16 = agree_on_bf16(agent.bf16, self.replicas)
            self._notice(f"agent.bf16: auto chose {'bf16' if agent.bf16 else 'float32'} on {self.device.type} "
                         "(bf16 where its timed matmul is faster, fbcpr.nn.precision)")
        if getattr(cfg.agent, "cuda_graph", False):
            assert isinstance(agent, GraphedAgent)  # as is one with a cuda_graph switch
            self._notice("agent.cuda_graph: " + ("the update is captured in a CUDA graph after 3 eager updates (a "
                         "capture that fails warns and runs eagerly)" if agent.graphed else
                         f"ignored on {self.device.type}"))

    @property
    def batching(self) -> BatchConfig:
        """The method's `agent:` section, for the batch and window sizes that every method sets."""
        return batch_config(self.cfg.agent)

    def _add_demonstrations(self, folder: Path, copies: int) -> None:
        """train.demonstrations: the folder's transitions, `copies` times, into the replay buffer (and its device
        copy)."""
        from motions.demonstrations import DemonstrationError, load_demonstrations, transitions

        cfg = self.cfg
        if cfg.env.name != "humanoid":
            raise ConfigError(f"train.demonstrations: demonstrations are humanoid motions, the env is {cfg.env.name!r}")
        if getattr(self.agent, "history", 0):
            raise ConfigError("train.demonstrations: this agent reads the states before each transition (a sequence "
                              "reward), which demonstrations added in one block do not keep")
        try:  # at most half of the buffer, copies counted
            demos = load_demonstrations(folder, max_transitions=cfg.train.buffer_capacity // 2 // copies,
                                        limit_name=f"half of train.buffer_capacity over {copies} demonstration_copies")
        except DemonstrationError as err:
            raise ConfigError(f"train.demonstrations: {err}") from None
        cloned = cfg.train.demonstration_share and getattr(cfg.agent, "bc_weight", 0.0)
        for d in demos:
            if d.action_mapping != cfg.env.action_mapping:
                raise ConfigError(f"train.demonstrations: {d.clip.name} was taken under the {d.action_mapping!r} "
                                  f"action mapping, the env uses {cfg.env.action_mapping!r}")
            if d.labels is not None and not cloned:
                raise ConfigError(f"train.demonstrations: {d.clip.name} carries an expert's labels, which only "
                                  "behaviour cloning reads: set train.demonstration_share and agent.bc_weight")
        block = {k: np.concatenate([v] * copies) for k, v in transitions(demos).items()}
        n = len(block["obs"])
        # one latent per demonstration and copy, as a rollout holds one per episode
        z = self.collector.sample_z(len(demos) * copies).cpu().numpy()
        block["z"] = np.repeat(z, [len(d.actions) for d in demos] * copies, axis=0)
        if cfg.train.demonstration_share:  # held apart, on the device the batches are drawn on
            dev = self.batches.device if self.batches is not None else torch.device("cpu")
            demo = {k: torch.as_tensor(block[k], dtype=torch.float32, device=dev) for k in self.agent.fields}
            # their marks (False and zeros on the replay rows): every row is one, "demo_next" where the demonstration
            # goes on, with the demonstrator's next action (a target that bootstraps on it:
            # agent.bootstrap_demo_actions)
            nxt = np.concatenate([np.concatenate([d.actions[1:], d.actions[-1:]]) for d in demos])
            last = np.concatenate([np.arange(len(d.actions)) == len(d.actions) - 1 for d in demos])
            demo["demo"] = torch.ones(n, dtype=torch.bool, device=dev)
            demo["demo_next"] = torch.as_tensor(~last, device=dev)
            demo["demo_next_action"] = torch.as_tensor(nxt, dtype=torch.float32, device=dev)
            target = np.concatenate([d.target for d in demos])  # labels where a rollout carries them (DAgger)
            demo["demo_target"] = torch.as_tensor(target, dtype=torch.float32, device=dev)
            self.learner.demos = demo
            self._notice(f"train.demonstrations: {len(demos)} demonstrations, {n:,} transitions held apart, "
                         f"{cfg.train.demonstration_share:.0%} of every batch")
            return
        rows = self.buffer.add(block)
        if self.batches is not None:
            self.batches.added(rows)
        self._notice(f"train.demonstrations: {len(demos)} demonstrations, {n:,} transitions in the replay buffer")

    # --------------------------------------------------------------------------------- main loop
    def run(self, max_env_steps: int | None = None, deadline: float | None = None) -> dict[str, Any]:
        """Train until total_env_steps (or max_env_steps more steps, or the `time.monotonic()` deadline, or a stop
        signal); returns a summary. The deadline is checked as often as a signal, so a time budget holds to within
        one update or tracking step plus the final checkpoint.

        A stop signal is sticky: later calls return at once with `interrupted=True`, so loops over chunks
        must check it."""
        tc = self.cfg.train
        self._deadline = math.inf if deadline is None else deadline
        stop_at = (tc.total_env_steps if max_env_steps is None
                   else min(tc.total_env_steps, self.env_steps + max_env_steps))
        handlers = self._install_signals()
        t0, steps0 = time.perf_counter(), self.env_steps
        self._run_t0 = t0
        steps_per_phase = phase_steps(tc, self.replicas.world_size)
        try:
            with self._progress(stop_at) as (progress, task):
                if self.next_eval == 0:  # train.eval_at_start: the model as it was loaded
                    self._periodic(t0, steps0, stop_at)
                    self._loaded_sample = None  # its only reader; a cached sample would be held for the run
                while self.env_steps < stop_at and not self._halt():
                    for _ in range(steps_per_phase):
                        self.env_steps += self.collector.step() * self.replicas.world_size
                        if self._halt():
                            break
                    ready = self._agree()
                    if self.env_steps >= self._updates_from and ready >= self.batching.batch_size:
                        for _ in range(tc.updates_per_rollout):
                            if self._halt():
                                break
                            self.learner.update()
                        self.collector.sync_policy()
                    if self._halt():
                        break
                    self._periodic(t0, steps0, stop_at)
                    if progress is not None:
                        progress.update(task, completed=self.env_steps, metrics=self._metric_text())
            # a run that did nothing (a resume already at its step count) leaves its checkpoint as it is
            path = self.save() if self.env_steps != self._saved_at else self._checkpoint_path()
        finally:
            self._wall_before, self._run_t0 = self.wall_s, None
            for sig, h in handlers.items():
                signal.signal(sig, h)
            if self._writer:
                self._writer.flush()
        return {"env_steps": self.env_steps, "updates": self.learner.updates, "checkpoint": str(path),
                "world_size": self.replicas.world_size, "interrupted": self._stop,
                "seconds": time.perf_counter() - t0, **self.learner.last_metrics}

    @property
    def wall_s(self) -> float:
        """Seconds this run has trained, over all its starts (resumes add to it): the x axis of wall-clock
        learning curves (`wall_s` in metrics.csv)."""
        return self._wall_before + (time.perf_counter() - self._run_t0 if self._run_t0 is not None else 0.0)

    def _halt(self) -> bool:
        """Stop at the next safe point: a stop signal came, or the run's deadline passed (under torchrun: the ranks
        agreed so at the end of the last rollout, see `_agree`)."""
        if self.replicas.enabled:
            return self._agreed_stop
        return self._stop or time.monotonic() >= self._deadline

    def _agree(self) -> int:
        """Once per rollout phase, the decisions every rank takes together: stop (any rank got a signal or passed
        its deadline) and the fill of the emptiest replay shard (updates start when every shard holds a batch).
        A single process decides alone."""
        if not self.replicas.enabled:
            return len(self.buffer)
        self._agreed_stop, ready = self.replicas.agree(self._stop or time.monotonic() >= self._deadline,
                                                       len(self.buffer))
        return ready

    # --------------------------------------------------------------------------------- periodic work
    def _periodic(self, t0: float, steps0: int, stop_at: int) -> None:
        tc = self.cfg.train
        extra: dict[str, float] = {}
        evaluated = self.env_steps >= self.next_priority or self.env_steps >= self.next_eval
        if evaluated:
            extra.update(self.evaluate(refresh_priorities=self.env_steps >= self.next_priority))
            while self.next_priority <= self.env_steps:
                self.next_priority += tc.priority_every
            while self.next_eval <= self.env_steps:
                self.next_eval += tc.eval_every
        # one process logs an evaluation that gave metrics; ranks log whenever they evaluated (the custom hook runs on
        # rank 0 only, so its metrics cannot decide for all, and a log row takes every rank's counts)
        if self.env_steps >= self.next_log or (evaluated if self.replicas.enabled else extra):
            fps = (self.env_steps - steps0) / max(time.perf_counter() - t0, 1e-9)
            episodes, dropped = self.replicas.sum(np.array([self.collector.episodes, self.buffer.dropped],
                                                           dtype=np.float64))
            row = {"env_steps": self.env_steps, "updates": self.learner.updates, "episodes": int(episodes),
                   "env_steps_per_s": fps, "wall_s": self.wall_s,
                   **self.replicas.mean_metrics(self.learner.last_metrics),
                   **self._take_action_stats(),
                   **extra}
            if dropped:
                row["buffer_dropped"] = int(dropped)
            self._log(row)
            self._warn(row)
            if self.replicas.is_main and not self.progress_enabled:
                self._log_line(stop_at, fps)
            while self.next_log <= self.env_steps:
                self.next_log += tc.log_every
        new_best = evaluated and self._new_best(extra)
        if self.env_steps >= self.next_ckpt or new_best:
            while self.next_ckpt <= self.env_steps:  # advanced first: the checkpoint records the next one
                self.next_ckpt += tc.checkpoint_every
            self.save()

    def _new_best(self, metrics: dict[str, float]) -> bool:
        """Whether this evaluation beat the best `train.keep_best` value so far (then it becomes the best, at this
        step's checkpoint). Rank 0 alone evaluates the custom hooks, so it decides for every rank."""
        tc = self.cfg.train
        if not tc.keep_best:
            return False
        value = metrics.get(tc.keep_best, math.nan)
        eligible = all(metrics.get(k, math.nan) >= floor for k, floor in tc.keep_best_requires.items())  # NaN: no
        better = eligible and math.isfinite(value) and (
            self.best is None or (value > self.best[0] if tc.keep_best_mode == "max" else value < self.best[0]))
        if not self.replicas.sum(np.array([float(better and self.replicas.is_main)]))[0]:
            return False
        if self.replicas.is_main:
            self.best = (value, self._checkpoint_path().name)
            self._notice(f"new best {tc.keep_best} {value:.4g} at {self.env_steps:,} env steps: checkpoints/best "
                         f"names {self.best[1]}")
        return True

    def evaluate(self, refresh_priorities: bool = False) -> dict[str, float]:
        """Track the clips (tracking EMD / success), optionally refresh priorities, plus the policy evaluations
        (`train.eval_upright`, `train.eval_tasks`) and the custom eval hook."""
        tc, r = self.cfg.train, self.replicas
        custom = self.custom_eval if r.is_main else None  # the custom hook runs once, on rank 0
        out = self._policy_eval() if (tc.eval_upright or tc.eval_tasks) and r.is_main else {}
        if not self.agent.z_dim:  # a single-task agent has no tracking prompt: only the hooks
            return {**out, **({f"eval/{k}": float(v) for k, v in custom(self.agent).items()} if custom else {})}
        rng = np.random.default_rng(self.env_steps)  # separate stream: evaluating never changes training
        failed = False
        try:  # under torchrun each rank tracks its share of the clips
            scores = tracking_scores(self.agent.model, self.bundle, self.batching.seq_length, tc.priority_max_clips,
                                     self.cfg.env.max_episode_steps, rng, stop=self._halt, shard=(r.rank, r.world_size))
        except EMDUnavailable as err:  # a run must not die for a missing metric package
            warnings.warn(f"tracking evaluation and priority refresh skipped, priorities stay as they are: {err}",
                          RuntimeWarning, stacklevel=2)
            scores, failed = {}, True
        scores = self._gather_scores(scores, failed)
        if scores is None:  # stopped mid-episode: no partial scores, priorities untouched
            return {}
        if scores:
            self.emd.update({name: e for name, (e, _) in scores.items()})
            out |= {"eval/tracking_emd": float(np.mean([e for e, _ in scores.values()])),
                    "eval/tracking_success": float(np.mean([s for _, s in scores.values()]))}
            if refresh_priorities:
                fill = float(np.median(list(self.emd.values())))
                self.bundle.library.set_priorities_from_emd({n: self.emd.get(n, fill)
                                                             for n in self.bundle.library.names})
        if custom is not None:
            out.update({f"eval/{k}": float(v) for k, v in custom(self.agent).items()})
        return out

    def _policy_eval(self) -> dict[str, float]:
        """The policy as it is now, prompted like a checkpoint would be (a BFM through the reward-inference
        sample; a single-task agent acts on its own), on the same starts at every evaluation:
        `train.eval_upright` (the stand prompt) and `train.eval_tasks` (returns, goal success)."""
        from fbcpr.eval.runner import EPISODE_STEPS, evaluate
        from fbcpr.eval.upright import upright_medians
        from fbcpr.inference.agents import live_agent

        tc = self.cfg.train
        agent = live_agent(self.agent.model, self.cfg, self._reward_sample()[0])
        steps = min(self.cfg.env.max_episode_steps, EPISODE_STEPS)  # 10 s, or a whole training episode if shorter
        out: dict[str, float] = {}
        if tc.eval_upright:
            out |= {f"eval/{k}": v for k, v in upright_medians(agent, tc.eval_upright, steps).items()}
        if tc.eval_tasks:
            res = evaluate(agent, "all", tasks=tc.eval_tasks, episodes=tc.eval_episodes, motions=self.bundle.library,
                           steps=steps, seed=tc.seed, show_progress=False)
            out |= {f"eval/return/{t}": r["return_mean"] for t, r in res.get("reward", {}).items()}
            out |= {f"eval/goal/{g}": r["success"] for g, r in res.get("goal", {}).items()}
            if "goal" in res["summary"]:
                out["eval/goal_success"] = res["summary"]["goal"]["success"]
        return out

    def _gather_scores(self, scores: dict[str, tuple[float, bool]] | None,
                       failed: bool) -> dict[str, tuple[float, bool]] | None:
        """Every rank's share of the tracking scores, on every rank (library order), so that all set the same
        priorities; None when any rank was stopped, {} when any lacked the EMD. One process: its own scores."""
        if not self.replicas.enabled:
            return scores
        names = self.bundle.library.names
        rows = np.zeros((len(names) + 1, 3))  # per clip: EMD, success, tracked; last row: stopped, failed
        rows[-1, :2] = scores is None, failed
        for name, (e, ok) in (scores or {}).items():
            rows[names.index(name)] = e, ok, 1.0
        rows = self.replicas.sum(rows)
        if rows[-1, 0]:
            return None
        if rows[-1, 1]:
            return {}
        return {n: (float(e), bool(ok)) for n, (e, ok, tracked) in zip(names, rows[:-1]) if tracked}

    def _take_action_stats(self) -> dict[str, float]:
        """Mean |action| and the saturated share of the policy's rollout actions since the last log row."""
        total, saturated, count = self.replicas.sum(self.collector.take_stats())
        return {"action_abs": total / count, "action_saturated": saturated / count} if count else {}

    def _warn(self, row: dict[str, float]) -> None:
        """Say plainly, once per run and signature, when training heads where failed public runs went."""
        for name, test, message in WARNINGS:
            if self.replicas.is_main and name not in self._warned and test(row):
                self._warned.add(name)
                Console(stderr=True).print(f"[yellow]warning at {self.env_steps:,} env steps: {message}[/]")
                with open(self.out / "warnings.txt", "a") as f:
                    f.write(f"{self.env_steps}\t{name}\t{message}\n")

    def _log(self, row: dict[str, float]) -> None:
        if not self.replicas.is_main:
            return
        if self._writer is None:
            self._writer = summary_writer(self.out / "tb") or False
        if self._writer:
            for k, v in row.items():
                if k != "env_steps":
                    self._writer.add_scalar(k, v, self.env_steps)
        new = not self.csv_path.exists()
        with open(self.csv_path, "a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["key", "value", "env_steps"])
            for k, v in row.items():
                w.writerow([k, f"{v:.6g}", self.env_steps])

    # --------------------------------------------------------------------------------- checkpoints
    def save(self) -> Path:
        """Checkpoint into out/checkpoints/step_XXXXXXXXXX and point out/checkpoints/latest at it (rank 0 writes,
        once every rank's learner is checked to be bit-identical to it; the rollout state is rank 0's)."""
        tc, r = self.cfg.train, self.replicas
        root = self.out / "checkpoints"
        path = root / f"step_{self.env_steps:010d}"
        tensors, meta = self.agent.state()
        r.check_replicated(self._learner_state(tensors, meta), "the learner state")
        episodes = int(r.sum(np.array([self.collector.episodes], dtype=np.float64))[0])
        if not r.is_main:
            self._saved_at = self.env_steps
            return path
        if isinstance(self.collector, Collector):  # the async collectors' envs are not saved
            tensors.update(self.collector.state())
        tensors.update({"torch_rng": torch.get_rng_state(),
                        "priorities": torch.as_tensor(np.asarray(self.bundle.library.priorities, dtype=np.float64))})
        if torch.cuda.is_available():
            tensors["cuda_rng"] = torch.cuda.get_rng_state()
        if self.batches is not None:
            tensors["device_batches_generator"] = self.batches.state()
        py_state = random.getstate()
        meta.update({
            "env_steps": self.env_steps, "updates": self.learner.updates, "episodes": episodes,
            "world_size": r.world_size,
            "next_priority": _num(self.next_priority), "next_eval": _num(self.next_eval),
            "next_ckpt": _num(self.next_ckpt), "next_log": self.next_log, "emd": self.emd, "wall_s": self.wall_s,
            "numpy_rng": self.rng.bit_generator.state, "numpy_global": _np_global_state(),
            "python_rng": [py_state[0], list(py_state[1]), py_state[2]],
            "buffer": {"size": len(self.buffer), "pos": self.buffer.pos},
            "env_rng": self.bundle.env.np_random.bit_generator.state,
            "best": None if self.best is None else {"metric": tc.keep_best, "mode": tc.keep_best_mode,
                                                    "requires": dict(tc.keep_best_requires),
                                                    "value": self.best[0], "checkpoint": self.best[1]},
        })
        reward, meta["reward_represents"] = self._reward_sample()
        replay = self.buffer.state() if tc.save_buffer else None
        save_checkpoint(path, self.agent.model, self.cfg, trainer_state=(tensors, meta), reward_buffer=reward,
                        replay_buffer=replay)
        write_pointer(root, "latest", path.name)
        if self.best is not None and self.best[1] == path.name:
            write_pointer(root, "best", path.name)  # before retention, which may remove the previous best
        self._saved_at = self.env_steps
        spared = {path.name, self.best[1] if self.best is not None else ""}
        for p in prunable_checkpoints(root, tc.keep_checkpoints, tc.keep_every):
            if p.name not in spared:
                discard_checkpoint(p)
        return path

    def _learner_state(self, tensors: dict[str, torch.Tensor], meta: dict[str, Any]) -> dict[str, torch.Tensor]:
        """What must be identical on every rank: the model and the agent's state tensors (targets, optimiser moments,
        imitation rewards), without its random streams (entries named `*generator`, which differ by rank)."""
        learner = {f"model.{k}": v for k, v in self.agent.model.state_dict().items()}
        learner.update({k: v for k, v in tensors.items() if not k.endswith("generator")})
        learner["updates"] = torch.tensor([self.learner.updates, int(meta.get("num_updates", 0))])
        return learner

    def _checkpoint_path(self) -> Path:
        return self.out / "checkpoints" / f"step_{self.env_steps:010d}"

    def _reward_sample(self) -> tuple[dict[str, np.ndarray] | None, int]:
        """The checkpoint's reward-inference sample and how many transitions it stands for.

        After a resume without the replay buffer, the sample carried over from the checkpoint is merged with the
        new transitions in proportion to what each stands for (as a FIFO buffer would hold them), so a resume
        never leaves reward prompts with less data than the run had."""
        if self._kept_sample is not None:
            return self._kept_sample, len(self._kept_sample["next_obs"])
        if not len(self.buffer) and self._loaded_sample is not None:  # a warm start before its first rollout
            loaded = self._loaded_sample()
            return loaded, 0 if loaded is None else len(loaded["next_obs"])
        n_max, rng = self.cfg.train.reward_buffer_size, np.random.default_rng(self.env_steps)
        new_n = len(self.buffer)
        if self._carried is None:
            fresh = self.buffer.reward_inference_sample(n_max, rng) if new_n and n_max else None
            return fresh, new_n
        carried_n = len(self._carried["next_obs"])
        old_n = max(0, min(self._carried_weight, self.cfg.train.buffer_capacity - new_n))  # pushed out by new data
        old_avail = round(carried_n * old_n / self._carried_weight) if self._carried_weight else 0
        n = min(n_max, old_avail + new_n)
        k_new = min(new_n, n - min(old_avail, round(n * old_n / max(old_n + new_n, 1))))
        k_old = min(old_avail, n - k_new)
        keep = np.sort(rng.choice(carried_n, k_old, replace=False))  # one draw for all arrays: rows stay transitions
        old = {k: v[keep] for k, v in self._carried.items()}
        if k_new:
            fresh = self.buffer.reward_inference_sample(k_new, rng)
            old = {k: np.concatenate([old[k], fresh[k]]) for k in old}
        return (old if k_old + k_new else None), old_n + new_n

    def close(self) -> None:
        """Remove the memory-mapped replay buffer: scratch space (a resume reads the checkpoint, never this), and
        a file as large as the whole buffer."""
        if isinstance(self.collector, CollectorPool):
            self.collector.close()
        if self.buffer.memmap_dir is not None:
            self.buffer.data.clear()
            shutil.rmtree(self.buffer.memmap_dir, ignore_errors=True)
        self.replicas.close()

    def _warm_start(self, src: str | Path) -> None:
        """Start from the weights of any checkpoint, inference-only ones included (the shipped model): networks,
        targets (= the networks) and normaliser; fresh optimisers and an empty replay buffer, which the warm-up
        fills with the loaded policy's own rollouts instead of random actions."""
        from fbcpr.inference.bfm import resolve_checkpoint
        from fbcpr.inference.reward_prompts import load_reward_prompts
        from fbcpr.methods.fb_cpr.model import FBCPRModel

        ckpt = load_checkpoint(resolve_checkpoint(src), self.device)
        if ckpt.algorithm != self.cfg.algorithm:
            raise ConfigError(f"algorithm: {self.cfg.algorithm!r} differs from {ckpt.algorithm!r} of the --init-from "
                              f"checkpoint {ckpt.path}")
        theirs = ckpt.config.env.action_mapping if isinstance(ckpt.config, Config) else None
        if theirs is not None and theirs != self.cfg.env.action_mapping:
            raise ConfigError(f"env.action_mapping: {self.cfg.env.action_mapping!r} differs from {theirs!r} of the "
                              f"--init-from checkpoint {ckpt.path}")
        load_state_strict(self.agent.model, ckpt.model.state_dict(), f"{ckpt.path / 'model.safetensors'} (--init-from)")
        sample = functools.cache(ckpt.reward_buffer)  # read at most once, and only where something needs it
        self._loaded_sample = sample if self.cfg.train.eval_at_start else None
        if self.cfg.train.keep_reward_sample:
            self._kept_sample = sample()
            if self._kept_sample is None:
                raise ConfigError(f"train.keep_reward_sample: the --init-from checkpoint {ckpt.path} has no "
                                  "reward-inference sample to keep")
        def stored_prompts() -> dict[str, np.ndarray] | None:  # checked against the loaded weights, when read
            stored = ckpt.reward_prompts()
            return None if stored is None else load_reward_prompts(*stored, cast(FBCPRModel, ckpt.model), ckpt.path).z

        self.agent.warm_started(sample, stored_prompts)

    def _resume(self) -> None:
        """Continue from the latest checkpoint. Every rank loads the learner state (model, targets, optimisers,
        counters, priorities); rank 0 also its rollout state (envs, random streams, replay buffer), while the
        other ranks of a torchrun start fresh shards, seeded from the base seed, their rank and the step."""
        ckpt = load_checkpoint(latest_checkpoint(self.out / "checkpoints"), self.device)
        load_state_strict(self.agent.model, ckpt.model.state_dict(), str(ckpt.path / "model.safetensors"))
        tensors, meta = ckpt.trainer_state()
        saved_envs = tensors["env_qpos"].shape[0] if "env_qpos" in tensors else self.cfg.train.num_envs
        if saved_envs != self.cfg.train.num_envs and self.replicas.is_main:
            raise ConfigError(f"train.num_envs: {self.cfg.train.num_envs}, but {ckpt.path} was saved with "
                              f"{saved_envs} envs; resume with num_envs: {saved_envs} (or start a new run)")
        self.agent.load_state(tensors, meta)
        if self.cfg.train.keep_reward_sample:
            self._kept_sample = ckpt.reward_buffer()
            if self._kept_sample is None:
                raise CheckpointError(f"{ckpt.path}: no reward-inference sample to keep (train.keep_reward_sample)")
        try:
            self.env_steps, self.learner.updates = meta["env_steps"], meta["updates"]
            self.collector.episodes = meta["episodes"]
            tc = self.cfg.train
            self.next_priority = rescheduled(_inf(meta["next_priority"]), tc.priority_every, self.env_steps)
            self.next_eval = rescheduled(_inf(meta["next_eval"]), tc.eval_every, self.env_steps)
            self.next_ckpt = rescheduled(_inf(meta["next_ckpt"]), tc.checkpoint_every, self.env_steps)
            self.next_log, self.emd = meta["next_log"], meta["emd"]
            self._wall_before = float(meta.get("wall_s", 0.0))  # checkpoints from before it was recorded: 0
            best = meta.get("best")
            record = (tc.keep_best, tc.keep_best_mode, tc.keep_best_requires)
            if best is not None and (best["metric"], best["mode"], best.get("requires", {})) == record:
                self.best = (float(best["value"]), str(best["checkpoint"]))  # another criterion starts a new record
            self.bundle.library.priorities = tensors["priorities"].numpy().copy()
            self._saved_at = self.env_steps
            if not ckpt.has(REPLAY_FILE):  # every rank: all of them start on empty shards, and must agree to update
                self._updates_from = self.env_steps + self.cfg.train.warmup_steps
            if not self.replicas.is_main:
                self._fresh_shard()
                return
            self.rng.bit_generator.state = meta["numpy_rng"]
            np.random.set_state(tuple(meta["numpy_global"]))
            v, st, gauss = meta["python_rng"]
            random.setstate((v, tuple(st), gauss))
            torch.set_rng_state(tensors["torch_rng"])
            if "cuda_rng" in tensors and torch.cuda.is_available():
                torch.cuda.set_rng_state(tensors["cuda_rng"])
            if self.batches is not None and "device_batches_generator" in tensors:  # else: a fresh stream
                self.batches.load_state(tensors["device_batches_generator"])
            if isinstance(self.collector, Collector) and "z" in tensors:
                try:  # the whole env state: the resumed envs step bit for bit as the saved ones would have
                    self.collector.load_state(tensors)
                except ValueError as err:  # the env's own error types included: another env or MuJoCo build
                    raise CheckpointError(f"{ckpt.path}/trainer_state.safetensors: {err}") from None
            elif isinstance(self.collector, Collector):  # saved by the async engine: new episodes
                self.collector.restart(int(np.random.SeedSequence((tc.seed, self.env_steps)).generate_state(1)[0]))
            else:  # the async collectors start new episodes, seeded by the step they start at
                self.collector.start_steps = self.env_steps
            self.bundle.env.np_random.bit_generator.state = meta["env_rng"]
        except KeyError as e:
            raise CheckpointError(f"{ckpt.path}/trainer_state.safetensors: missing entry {e}") from None
        replay = ckpt.replay_buffer()
        if replay is not None:
            self.buffer.load_state(*replay)
            if self.batches is not None:
                self.batches.reload()
            return
        if self.cfg.train.save_buffer:
            raise CheckpointError(f"{ckpt.path}: train.save_buffer is set but the checkpoint has no replay buffer")
        self._carried = ckpt.reward_buffer() if self._kept_sample is None else None
        if self._kept_sample is not None:
            lost = "its reward-inference sample, the loaded model's, is kept as it is (train.keep_reward_sample)"
        elif self._carried is not None and inconsistent_rows(self._carried, self.cfg.env.name) > 0.5:
            self._carried = None
            lost = ("its reward-inference sample is dropped: its rows mix different transitions (saved by a resume "
                    "before this was checked), so reward prompts will only see the new transitions")
        elif self._carried is None:
            lost = "it has no reward-inference sample either: reward prompts will only see the new transitions"
        else:
            self._carried_weight = int(meta.get("reward_represents", meta["buffer"]["size"]))
            lost = (f"its reward-inference sample ({len(self._carried['next_obs']):,} states) is carried over and "
                    "merged with the new transitions")
        self._notice(f"resume: {ckpt.path} has no replay buffer (train.save_buffer: false), so training continues "
                     f"from an empty buffer, which the loaded policy refills for {self.cfg.train.warmup_steps:,} env "
                     f"steps before updates go on; {lost}. Set train.save_buffer: true for an exact resume.")

    def _fresh_shard(self) -> None:
        """A resumed rank other than 0: new envs, random streams and latents, seeded from (seed + rank, env steps)
        so they neither repeat the run's start nor depend on the world size of the run that saved the checkpoint."""
        seeds = np.random.SeedSequence((self.cfg.train.seed + self.replicas.rank, self.env_steps)).generate_state(4)
        random.seed(int(seeds[0]))
        np.random.seed(int(seeds[0]))
        self.rng.bit_generator.state = np.random.default_rng(int(seeds[1])).bit_generator.state  # the parts share it
        torch.manual_seed(int(seeds[2]))
        self.agent.generator.manual_seed(int(seeds[2]))
        if self.batches is not None:
            self.batches.generator.manual_seed(int(seeds[2]))
        assert isinstance(self.collector, Collector)  # torchrun runs the sync engine (check_async)
        self.collector.restart(int(seeds[3]))

    # --------------------------------------------------------------------------------- plumbing
    def _install_signals(self) -> dict[int, Any]:
        """SIGINT, SIGTERM and SIGHUP (the terminal went away) stop at the next safe point, within one env step,
        update or tracking step, with a final checkpoint; a second one aborts at once (KeyboardInterrupt), the
        last checkpoint on disk staying intact (checkpoints are written atomically)."""
        def stop(signum: int, frame: Any) -> None:
            if self._stop:
                raise KeyboardInterrupt
            self._stop = True
            try:  # straight to the fd: safe inside a signal handler, and fine if the terminal is gone
                os.write(2, "\nstopping… writing a final checkpoint (signal again to abort at once)\n".encode())
            except OSError:
                pass

        old = {}
        for sig in STOP_SIGNALS:
            try:
                old[sig] = signal.signal(sig, stop)
            except ValueError:  # not the main thread
                pass
        return old

    def _notice(self, message: str) -> None:
        """A yellow line on stderr that is also kept in the run's warnings.txt (rank 0's only)."""
        if not self.replicas.is_main:
            return
        Console(stderr=True).print(f"[yellow]{message}[/]", highlight=False, soft_wrap=True)  # one line in logs
        with open(self.out / "warnings.txt", "a") as f:
            f.write(f"{self.env_steps}\tnotice\t{message}\n")

    def _metric_text(self) -> str:
        """Compact live metrics for the progress bar, e.g. `u 1,200 fb 3.1 act -12 crit 0.4`."""
        short = {"fb_loss": "fb", "actor_loss": "act", "critic_loss": "crit", "disc_loss": "disc", "reward": "r"}
        metrics = self.learner.last_metrics
        parts = [f"{short[k]} {metrics[k]:.2g}" for k in LIVE_KEYS if k in metrics]
        return " ".join([f"u {self.learner.updates:,}", *parts])

    def _log_line(self, total: int, rate: float) -> None:
        """One plain progress line (for logs and CI, where the live bar is off), on stderr where the bar would be, so
        a script's own output on stdout stays its own."""
        left = int((total - self.env_steps) / rate) if rate > 0 else None
        eta = "?" if left is None else f"{left // 3600}:{left % 3600 // 60:02d}:{left % 60:02d}"
        print(f"{self.env_steps:,}/{total:,} steps ({100 * self.env_steps / total:.1f}%) {rate:,.0f} steps/s "
              f"eta {eta} | {self._metric_text()}", file=sys.stderr, flush=True)

    @contextmanager
    def _progress(self, total: int) -> Iterator[tuple[Progress | None, Any]]:
        """A rich progress bar over env steps on stderr (or nothing when disabled)."""
        if not self.progress_enabled:
            yield None, None
            return
        with Progress(*progress_columns(), console=Console(stderr=True), transient=False, expand=True) as progress:
            yield progress, progress.add_task("training", total=total, completed=self.env_steps,
                                              metrics=self._metric_text())


def check_async(cfg: Config, world_size: int) -> None:
    """ConfigError unless the async engine can run `cfg`: its envs split evenly over the collectors, in one
    process (the collectors are its data parallelism)."""
    tc = cfg.train
    if tc.num_envs % tc.collectors:
        raise ConfigError(f"train.collectors: {tc.collectors} collectors do not split train.num_envs: {tc.num_envs} "
                          "evenly; use a divisor of num_envs")
    if world_size > 1:
        raise ConfigError(f"train.engine: async runs in one process and {world_size} ranks were launched; use "
                          "train.collectors for more envs, or train.engine: sync under torchrun")


def config_json(cfg: Config) -> str:
    """The run config as canonical JSON (what the ranks of one run must agree on)."""
    return json.dumps(asdict(cfg), sort_keys=True, default=str)


def _check_fresh(cfg: Config) -> None:
    """ConfigError for keys that continue a loaded model, in a run that starts from scratch."""
    held = cfg.agent.holds_loaded_model() + (["train.keep_reward_sample"] if cfg.train.keep_reward_sample else [])
    if held:
        raise ConfigError(f"{held[0]}: holds a run near the model it continues, so it needs --init-from "
                          "(a fresh run has no model to hold)")
    if cfg.train.eval_at_start:
        raise ConfigError("train.eval_at_start: evaluates the model a run continues, so it needs --init-from")


def agree_on_bf16(chosen: bool, replicas: distributed.Replicas) -> bool:
    """`agent.bf16: auto` under torchrun: each rank timed its own matmul, and the ranks take bf16 only if all chose
    it, so that every replica computes its gradients in one precision."""
    return bool(replicas.sum(np.array([float(chosen)]))[0] == replicas.world_size) if replicas.enabled else chosen


def _num(x: float) -> float | None:
    return None if math.isinf(x) else x


def _inf(x: float | None) -> float:
    return math.inf if x is None else x


def _np_global_state() -> list[Any]:
    state = np.random.get_state()
    assert isinstance(state, tuple)  # the global RandomState is an MT19937, whose legacy state is a tuple
    name, keys, pos, has_gauss, cached = state
    return [name, keys.tolist(), int(pos), int(has_gauss), float(cached)]


def train(cfg: Config, out_dir: str | Path, resume: bool = False, progress: bool = True,
          init_from: str | Path | None = None) -> dict[str, Any]:
    """Build a Trainer and run it to the end (or until interrupted); `init_from` warm-starts a new run."""
    trainer = Trainer(cfg, out_dir, resume=resume, progress=progress, init_from=init_from)
    try:
        summary = trainer.run()
    finally:
        trainer.close()
    if trainer.replicas.is_main:
        (Path(out_dir) / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return summary


def resume_refill_steps(run_dir: str | Path, cfg: Config) -> int:
    """Env steps a resume of `run_dir` spends refilling an empty replay buffer before updates go on: the config's
    warm-up when the latest checkpoint holds no replay buffer (train.save_buffer: false), else 0."""
    path = latest_checkpoint(Path(run_dir) / "checkpoints")
    saved = read_manifest(path / MANIFEST_FILE).get("files", {})
    return 0 if REPLAY_FILE in saved else cfg.train.warmup_steps


def checkpoint_env_steps(run_dir: str | Path) -> int:
    """Env steps of a run directory's latest checkpoint (read from its trainer-state header only)."""
    path = latest_checkpoint(Path(run_dir) / "checkpoints")
    try:
        return int(read_trainer_meta(path)["env_steps"])
    except KeyError:
        raise CheckpointError(f"{path}: trainer state without env_steps") from None
