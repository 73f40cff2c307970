"""Collectors in worker processes (`train.engine: async`): envs that step while the learner updates.

Each of `train.collectors` processes steps its share of the run's envs (num_envs / collectors) with its own copy of
the policy, and writes each vector step into a slot of a ring in shared memory; the trainer's process moves filled
slots into the replay buffer (one slot of every collector per `step`, so an env's previous transition stays
num_envs rows back) and hands the slots back. A collector runs ahead of the learner by at most its ring
(`ring_slots`: two rollout phases), then waits for a free slot: the trainer keeps the update-to-data ratio of the
config exactly (it drains a phase, then runs its updates, while the collectors fill the next phase), and the
policy the collectors act with is at most two phases older than the learner's. After every phase of updates
`sync_policy` copies the weights that acting reads (`acting_weights`) and the motion priorities into shared memory,
where each collector picks them up before its next step.

Differences from the in-process collector (`fbcpr.train.collector`): a collector's rollout latents take their
online states from its own last `ONLINE_ROWS` transitions (not the whole replay buffer), the envs' state is not
checkpointed (a resumed run starts new episodes, seeded by the collector and the env step), and runs are not
reproducible bit for bit (which weights a step acts with depends on timing).
"""
from __future__ import annotations

import os
import queue
import signal
from dataclasses import replace
from typing import Any

import numpy as np
import torch
import torch.multiprocessing as mp

from fbcpr.core.errors import FBCPRError
from fbcpr.core.protocols import EnvBundle, OnlineAgent
from fbcpr.core.registry import get_method
from fbcpr.core.schema import Config, batch_config
from fbcpr.envs.bundle import make_env
from fbcpr.train.buffer import ReplayBuffer
from fbcpr.train.collector import action_stats, buffer_latents, rollout_latents
from fbcpr.train.device_batches import DeviceBatches
from fbcpr.train.schedule import phase_steps

#: online next states each collector keeps for its rollout latents
ONLINE_ROWS = 10_000
#: seconds between checks that a collector is still alive while waiting for its next slot
POLL_S = 1.0
#: Signals that end a run at the next safe point with a checkpoint: Ctrl-C, `kill`, and the terminal going away. The
#: trainer handles them; the collectors ignore them.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


class CollectorError(FBCPRError, RuntimeError):
    """A collector process died (its traceback is printed above this error)."""


def ring_slots(cfg: Config) -> int:
    """Slots of each collector's ring: two rollout phases, so the collectors step on through a phase of updates."""
    return max(2, 2 * phase_steps(cfg.train, 1))


def acting_weights(agent: OnlineAgent) -> dict[str, torch.Tensor]:
    """The model's tensors that acting reads: those of the agent's `acting_modules` (FB-CPR's normaliser, actor and
    B: the collectors copy them after every phase of updates, so the critics' weights would be copies for nothing),
    else all of them."""
    modules = getattr(agent, "acting_modules", None)
    return {k: v for k, v in agent.model.state_dict().items() if modules is None or k.split(".")[0] in modules}


def collector_threads(cfg: Config, cores: int) -> int:
    """MuJoCo threads of each collector: train.env_threads, else the cores shared by the collectors and the learner."""
    return cfg.train.env_threads or max(1, cores // (cfg.train.collectors + 1))


class CollectorPool:
    """`train.collectors` worker processes, with the in-process collector's interface (`step`, `sample_z`,
    `sync_policy`, `take_stats`, `episodes`, `random_steps`, `close`). The workers start on the first `step`."""

    def __init__(self, cfg: Config, bundle: EnvBundle, agent: OnlineAgent, buffer: ReplayBuffer,
                 batches: DeviceBatches | None, rng: np.random.Generator, device: torch.device, cores: int) -> None:
        tc = cfg.train
        self.cfg, self.bundle, self.agent, self.buffer, self.batches = cfg, bundle, agent, buffer, batches
        self.rng, self.device, self.cores = rng, device, cores
        self.per_worker = tc.num_envs // tc.collectors
        self.random_steps = 0
        self.episodes = 0
        self.stats = np.zeros(3)
        self.start_steps = 0  # the run's env steps when the workers start (seeds their envs)
        slots, n = ring_slots(cfg), self.per_worker
        self.rings = [{k: torch.zeros((slots, n, *shape)).share_memory_() for k, shape in buffer.specs.items()}
                      | {"done": torch.zeros((slots, n), dtype=torch.bool).share_memory_(),
                         "policy": torch.zeros(slots, dtype=torch.bool).share_memory_()}
                      for _ in range(tc.collectors)]
        self.weights = {k: v.detach().to("cpu", copy=True).share_memory_() for k, v in acting_weights(agent).items()}
        self.priorities = torch.as_tensor(np.asarray(bundle.library.priorities, dtype=np.float64)).share_memory_()
        self.ctx = mp.get_context("spawn")  # fresh interpreters: no forked torch or MuJoCo thread pools
        self.version = self.ctx.Value("q", 0)
        self.lock = self.ctx.Lock()
        self.stop = self.ctx.Event()
        self.free = [self.ctx.Queue() for _ in range(tc.collectors)]
        self.filled = [self.ctx.Queue() for _ in range(tc.collectors)]
        self.procs: list[Any] = []

    def _start(self) -> None:
        tc = self.cfg.train
        self.sync_policy()
        # the workers act on the CPU in float32, eagerly, whatever the learner's device, precision and compilation
        agent_cfg = replace(self.cfg.agent, **{k: False for k in ("bf16", "cuda_graph", "compile")
                                               if hasattr(self.cfg.agent, k)})
        cfg = replace(self.cfg, agent=agent_cfg, train=replace(tc, device="cpu", device_buffer=False))
        threads = collector_threads(self.cfg, self.cores)
        for i, ring in enumerate(self.rings):
            seed = int(np.random.SeedSequence((tc.seed, i, self.start_steps)).generate_state(1)[0])
            for slot in range(len(ring["policy"])):
                self.free[i].put(slot)
            proc = self.ctx.Process(target=collect, name=f"fbcpr-collector-{i}", daemon=True,
                                    args=(cfg, self.per_worker, seed, threads, self.random_steps, ring, self.weights,
                                          self.priorities, self.version, self.lock, self.free[i], self.filled[i],
                                          self.stop))
            proc.start()
            self.procs.append(proc)

    def sample_z(self, n: int) -> torch.Tensor:
        """n rollout latents drawn in this process (demonstrations added to the buffer carry them)."""
        return buffer_latents(self.cfg, self.agent, self.bundle.library, self.buffer, self.rng, n)

    def step(self) -> int:
        """One filled slot of every collector into the replay buffer (waiting for it); returns num_envs."""
        if not self.procs:
            self._start()
        for i, ring in enumerate(self.rings):
            slot = self._next_filled(i)
            block = {k: ring[k][slot].numpy() for k in self.buffer.specs}
            rows = self.buffer.add(block)
            if self.batches is not None:
                self.batches.added(rows)
            if hasattr(self.agent, "observe"):  # agents that track their own progress (NEAR's annealing)
                self.agent.observe(torch.as_tensor(block["obs"]), torch.as_tensor(block["next_obs"]),
                                   torch.as_tensor(block["z"], device=self.device))
            if ring["policy"][slot]:
                self.stats += action_stats(block["action"])
            self.episodes += int(ring["done"][slot].sum())
            self.free[i].put(slot)
        self.random_steps = max(0, self.random_steps - 1)
        return self.cfg.train.num_envs

    def _next_filled(self, i: int) -> int:
        while True:
            try:
                return int(self.filled[i].get(timeout=POLL_S))
            except queue.Empty:
                proc = self.procs[i]
                if not proc.is_alive():
                    raise CollectorError(f"train.engine async: collector {i} exited with code {proc.exitcode} "
                                         "(its error is printed above)") from None

    def sync_policy(self) -> None:
        """Copy the learner's weights and the motion priorities to the collectors (they take them before their
        next step)."""
        with self.lock:
            for k, v in acting_weights(self.agent).items():
                self.weights[k].copy_(v)
            self.priorities.copy_(torch.as_tensor(np.asarray(self.bundle.library.priorities, dtype=np.float64)))
            self.version.value += 1

    def take_stats(self) -> np.ndarray:
        """The action statistics since the last call (then reset)."""
        out = self.stats.copy()
        self.stats[:] = 0
        return out

    def close(self) -> None:
        """Stop the workers (each ends within a poll once the stop is set) and release the queues."""
        self.stop.set()
        for proc in self.procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.terminate()
                proc.join()
        for q in (*self.free, *self.filled):
            q.cancel_join_thread()
            q.close()
        self.procs = []


def collect(cfg: Config, n: int, seed: int, threads: int, random_steps: int, ring: dict[str, torch.Tensor],
            weights: dict[str, torch.Tensor], priorities: torch.Tensor, version: Any, lock: Any, free: Any,
            filled: Any, stop: Any) -> None:
    """A collector process: steps n envs, one ring slot per vector step, until `stop` is set or the trainer's
    process is gone. Stop signals are the trainer's to handle (a Ctrl-C or `timeout` reaches the whole process
    group): the trainer stops at its next safe point with a checkpoint, then sets `stop`."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    parent = os.getppid()
    torch.set_num_threads(1)
    tc = cfg.train
    bundle = make_env(cfg.env, n, seed, threads)
    cfg = replace(cfg, model=replace(cfg.model, obs_dim=bundle.obs_dim, action_dim=bundle.action_dim))
    torch.manual_seed(seed)
    agent = get_method(cfg.algorithm).agent(cfg, bundle, torch.device("cpu"), seed)
    rng = np.random.default_rng(seed)
    seq_length = batch_config(cfg.agent).seq_length
    online = np.zeros((ONLINE_ROWS, bundle.obs_dim), dtype=np.float32)
    held = pos = 0  # online rows filled so far, and where the next ones go (first in, first out)
    seen = -1
    obs, _ = bundle.env.reset(seed=seed)
    z = torch.zeros((n, agent.z_dim))
    z_age = np.full(n, tc.z_update_every, dtype=np.int64)
    steps = 0
    while not stop.is_set() and os.getppid() == parent:
        try:
            slot = free.get(timeout=0.2)
        except queue.Empty:
            continue
        if version.value != seen:
            with lock:
                unexpected = agent.model.load_state_dict(weights, strict=False).unexpected_keys
                assert not unexpected, unexpected  # the weights of the modules acting reads, and only those
                bundle.library.priorities = priorities.numpy().copy()
                seen = version.value
        stale = np.flatnonzero(z_age >= tc.z_update_every)
        if len(stale):
            states = online[rng.integers(0, held, size=len(stale))] if held else None
            z[torch.as_tensor(stale)] = rollout_latents(agent, bundle.library, states, rng, len(stale), seq_length)
            z_age[stale] = 0
        policy = steps >= random_steps
        if policy:
            with torch.no_grad():
                action = agent.act(torch.as_tensor(obs), z).numpy()
        else:
            action = rng.uniform(-1.0, 1.0, size=(n, bundle.action_dim)).astype(np.float32)
        next_obs, _, terminated, truncated, info = bundle.env.step(action)
        done = np.asarray(terminated | truncated)
        for key, value in (("obs", obs), ("action", action), ("next_obs", info["final_obs"]), ("z", z.numpy()),
                           ("qpos", info["final_qpos"]), ("qvel", info["final_qvel"]), ("terminated", terminated)):
            ring[key][slot] = torch.as_tensor(np.asarray(value, dtype=np.float32))
        ring["done"][slot] = torch.as_tensor(done)
        ring["policy"][slot] = policy
        filled.put(slot)
        online[(pos + np.arange(n)) % ONLINE_ROWS] = info["final_obs"]
        pos, held = (pos + n) % ONLINE_ROWS, min(held + n, ONLINE_ROWS)
        obs = next_obs
        z_age += 1
        z_age[done] = tc.z_update_every
        steps += 1
