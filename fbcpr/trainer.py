"""Online training loop of every method (Algorithm 1 with the protocol of App. C.5.1 for FB-CPR).

Each iteration collects `rollout_steps` transitions from `num_envs` parallel envs (random actions during
warm-up, then the policy with z ~ nu resampled every `z_update_every` steps), then runs
`updates_per_rollout` gradient steps. The agent is the config's `algorithm` (`fbcpr.methods`), driven
through `fbcpr.protocols.OnlineAgent`; z is its rollout latent (empty for single-task agents). Every `priority_every` env steps the policy tracks the clips and the
motion priorities are reset from the tracking EMD (1/|bin| scheme of App. C.4). Checkpoints carry the
model, the exact learner state (target nets, optimisers, normaliser, counters, RNG states, env states and
optionally the replay buffer) and a reward-inference subsample of the buffer. SIGINT/SIGTERM ends the
run at the next safe point with a final checkpoint. Optional packages degrade with one warning each: without
tensorboard metrics go to metrics.csv only; without any EMD solver (POT, or scipy for the equal-length
fallback) tracking evaluation and the priority refresh are skipped.
"""
from __future__ import annotations

import csv
import json
import math
import os
import random
import shutil
import signal
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from rich.console import Console
from rich.progress import BarColumn, Progress, ProgressColumn, Task, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Column
from rich.text import Text

from fbcpr.buffer import ReplayBuffer, transition_specs
from fbcpr.checkpoint import (
    CheckpointError,
    discard_checkpoint,
    latest_checkpoint,
    load_checkpoint,
    load_state_strict,
    read_trainer_meta,
    remove_stale_temporaries,
    save_checkpoint,
)
from fbcpr.config import Config, ConfigError
from fbcpr.envs import EnvBundle, make_env, tracking_scores
from fbcpr.evaluation.metrics import EMDUnavailable
from fbcpr.methods import get_method
from fbcpr.protocols import OnlineAgent

LIVE_KEYS = ("fb_loss", "actor_loss", "critic_loss", "disc_loss", "reward")
#: |action| beyond which a component counts as saturated (at a joint limit's side of the PD range).
SATURATED = 0.9
#: Failure signatures reported by public FB-CPR users, checked at every log row: (name, test, message).
WARNINGS: tuple[tuple[str, Callable[[dict[str, float]], bool], str], ...] = (
    ("discriminator", lambda m: m.get("disc_expert", 0.0) > 0.95 and m.get("disc_online", 1.0) < 0.05,
     "the discriminator separates expert from online states almost perfectly: the imitation reward is a constant "
     "penalty and the actor learns little from it (a signature of runs that end lying on the ground)"),
    ("bang-bang", lambda m: m.get("action_saturated", 0.0) > 0.5,
     "over half of the policy's action components sit beyond 0.9: a bang-bang actor, which falls"),
    ("non-finite", lambda m: m.get("buffer_dropped", 0) > 0,
     "transitions with NaN or inf values reached the replay buffer and were dropped (see buffer_dropped)"),
)


#: Signals that end a run at the next safe point with a checkpoint: Ctrl-C, `kill`, and the terminal going away.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


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
        self.progress_enabled = progress
        self.custom_eval = evaluate
        tc = cfg.train
        if tc.torch_threads:
            torch.set_num_threads(tc.torch_threads)
        self.device = resolve_device(tc.device)  # device and env fail before the run directory exists
        self.bundle: EnvBundle = make_env(cfg.env, tc.num_envs, tc.seed)
        b = self.bundle
        for key, have in (("obs_dim", b.obs_dim), ("action_dim", b.action_dim)):
            given = getattr(cfg.model, key)
            if given is not None and given != have:
                raise ConfigError(f"model.{key}: {given} does not match the {cfg.env.name} env ({have})")
        self.cfg = cfg = replace(cfg, model=replace(cfg.model, obs_dim=b.obs_dim, action_dim=b.action_dim))
        if cfg.agent.batch_size > tc.buffer_capacity:
            raise ConfigError("train.buffer_capacity: must be >= agent.batch_size")
        self._memmap_buffer = check_memory(cfg, b.nq, b.nv, self.out, self.device)

        random.seed(tc.seed)
        np.random.seed(tc.seed)
        self.rng = np.random.default_rng(tc.seed)
        self.agent = get_method(cfg.algorithm).agent(cfg, b, self.device, tc.seed)
        self.warm_started = init_from is not None and not resume
        if self.warm_started:
            self._warm_start(init_from)
        self.out.mkdir(parents=True, exist_ok=True)
        if (self.out / "checkpoints").is_dir():
            remove_stale_temporaries(self.out / "checkpoints")
        specs = transition_specs(b.obs_dim, b.action_dim, self.agent.z_dim, b.nq, b.nv)
        self.buffer = ReplayBuffer(tc.buffer_capacity, specs, self.out / "buffer_mmap" if self._memmap_buffer else None,
                                   stride=tc.num_envs)

        self.env_steps = self.updates = self.episodes = 0
        self.next_priority = tc.priority_every or math.inf
        self.next_eval = tc.eval_every or math.inf
        self.next_ckpt = tc.checkpoint_every or math.inf
        self.next_log = 0
        self.emd: dict[str, float] = {}
        self.last_metrics: dict[str, float] = {}
        self._action_stats = np.zeros(3)  # sum |a|, saturated components, components (policy actions only)
        self._warned: set[str] = set()
        self._stop = False
        self._deadline = math.inf  # time.monotonic() at which run() stops (its `deadline`)
        self._saved_at: int | None = None  # env steps of the checkpoint on disk (none yet)
        # reward-inference sample carried over a resume without the replay buffer, and how many transitions it stands for
        self._carried: dict[str, np.ndarray] | None = None
        self._carried_weight = 0
        self._last_line = 0.0
        self.obs, info = b.env.reset(seed=tc.seed)
        self.z = self._sample_rollout_z(tc.num_envs)
        self.z_age = np.zeros(tc.num_envs, dtype=np.int64)
        if resume:
            self._resume()
        self.csv_path = self.out / "metrics.csv"
        self._writer: Any = None  # SummaryWriter once created, False where tensorboard is missing

    # --------------------------------------------------------------------------------- z for rollouts
    def _sample_rollout_z(self, n: int) -> torch.Tensor:
        """n rollout latents from the agent (FB-CPR's nu) given online states from the buffer and demo windows."""
        L = self.cfg.agent.seq_length
        online = self.buffer.sample(self.rng, n, fields=("next_obs",))["next_obs"] if len(self.buffer) > 0 else None
        windows = torch.as_tensor(self.bundle.library.sample_windows(self.rng, n, L))
        return self.agent.rollout_z(n, online, windows)

    # --------------------------------------------------------------------------------- main loop
    def run(self, max_env_steps: int | None = None, deadline: float | None = None) -> dict[str, Any]:
        """Train until total_env_steps (or max_env_steps more steps, or the `time.monotonic()` deadline, or a stop
        signal); returns a summary. The deadline is checked as often as a signal, so a time budget holds to within
        one update or tracking step plus the final checkpoint.

        A stop signal is sticky: later calls return at once with `interrupted=True`, so loops over chunks
        must check it."""
        tc = self.cfg.train
        self._deadline = math.inf if deadline is None else deadline
        stop_at = tc.total_env_steps if max_env_steps is None else min(tc.total_env_steps, self.env_steps + max_env_steps)
        handlers = self._install_signals()
        t0, steps0 = time.perf_counter(), self.env_steps
        steps_per_phase = max(1, math.ceil(tc.rollout_steps / tc.num_envs))
        try:
            with self._progress(stop_at) as (progress, task):
                while self.env_steps < stop_at and not self._halt():
                    for _ in range(steps_per_phase):
                        self._env_step()
                        if self._halt():
                            break
                    if self.env_steps >= tc.warmup_steps and len(self.buffer) >= self.cfg.agent.batch_size:
                        for _ in range(tc.updates_per_rollout):
                            if self._halt():
                                break
                            self._update()
                    if self._halt():
                        break
                    self._periodic(t0, steps0, stop_at)
                    if progress is not None:
                        progress.update(task, completed=self.env_steps, metrics=self._metric_text())
            # a run that did nothing (a resume already at its step count) leaves its checkpoint as it is
            path = self.save() if self.env_steps != self._saved_at else self._checkpoint_path()
        finally:
            for sig, h in handlers.items():
                signal.signal(sig, h)
            if self._writer:
                self._writer.flush()
        return {"env_steps": self.env_steps, "updates": self.updates, "checkpoint": str(path),
                "interrupted": self._stop, "seconds": time.perf_counter() - t0, **self.last_metrics}

    def _halt(self) -> bool:
        """Stop at the next safe point: a stop signal came, or the run's deadline passed."""
        return self._stop or time.monotonic() >= self._deadline

    def _env_step(self) -> None:
        tc, agent, env = self.cfg.train, self.agent, self.bundle.env
        n = tc.num_envs
        stale = np.flatnonzero(self.z_age >= tc.z_update_every)
        if len(stale):
            self.z[torch.as_tensor(stale, device=self.device)] = self._sample_rollout_z(len(stale))
            self.z_age[stale] = 0
        if self.env_steps < tc.warmup_steps and not self.warm_started:
            action = self.rng.uniform(-1.0, 1.0, size=(n, self.bundle.action_dim)).astype(np.float32)
        else:
            action = agent.act(torch.as_tensor(self.obs, device=self.device), self.z).cpu().numpy()
            mag = np.abs(action)
            self._action_stats += (mag.sum(), (mag > SATURATED).sum(), mag.size)
        next_obs, _, terminated, truncated, info = env.step(action)
        self.buffer.add({"obs": self.obs, "action": action, "next_obs": info["final_obs"], "z": self.z.cpu().numpy(),
                         "qpos": info["final_qpos"], "qvel": info["final_qvel"], "terminated": terminated})
        done = np.asarray(terminated | truncated)
        self.obs = next_obs
        self.z_age += 1
        self.z_age[done] = tc.z_update_every  # a new episode gets a new z
        self.episodes += int(done.sum())
        self.env_steps += n

    def _update(self) -> None:
        a = self.cfg.agent
        batch = self.buffer.sample(self.rng, a.batch_size, fields=self.agent.fields,
                                   history=getattr(self.agent, "history", 0))  # states before obs: sequence rewards
        windows = torch.as_tensor(self.bundle.library.sample_windows(self.rng, a.batch_size // a.seq_length, a.seq_length))
        self.last_metrics = self.agent.update(batch, windows)
        self.updates += 1

    # --------------------------------------------------------------------------------- periodic work
    def _periodic(self, t0: float, steps0: int, stop_at: int) -> None:
        tc = self.cfg.train
        extra: dict[str, float] = {}
        if self.env_steps >= self.next_priority or self.env_steps >= self.next_eval:
            extra.update(self.evaluate(refresh_priorities=self.env_steps >= self.next_priority))
            while self.next_priority <= self.env_steps:
                self.next_priority += tc.priority_every
            while self.next_eval <= self.env_steps:
                self.next_eval += tc.eval_every
        if self.env_steps >= self.next_log or extra:
            fps = (self.env_steps - steps0) / max(time.perf_counter() - t0, 1e-9)
            row = {"env_steps": self.env_steps, "updates": self.updates, "episodes": self.episodes,
                   "env_steps_per_s": fps, **self.last_metrics, **self._take_action_stats(), **extra}
            if self.buffer.dropped:
                row["buffer_dropped"] = self.buffer.dropped
            self._log(row)
            self._warn(row)
            if not self.progress_enabled:
                self._log_line(stop_at, fps)
            while self.next_log <= self.env_steps:
                self.next_log += tc.log_every
        if self.env_steps >= self.next_ckpt:
            while self.next_ckpt <= self.env_steps:  # advanced first: the checkpoint records the next one
                self.next_ckpt += tc.checkpoint_every
            self.save()

    def evaluate(self, refresh_priorities: bool = False) -> dict[str, float]:
        """Track the clips (tracking EMD / success), optionally refresh priorities, plus the custom eval hook."""
        tc = self.cfg.train
        if not self.agent.z_dim:  # a single-task agent has no tracking prompt: only the custom hook
            return {f"eval/{k}": float(v) for k, v in self.custom_eval(self.agent).items()} if self.custom_eval else {}
        rng = np.random.default_rng(self.env_steps)  # separate stream: evaluating never changes training
        out: dict[str, float] = {}
        try:
            scores = tracking_scores(self.agent.model, self.bundle, self.cfg.agent.seq_length, tc.priority_max_clips,
                                     self.cfg.env.max_episode_steps, rng, stop=self._halt)
        except EMDUnavailable as err:  # a run must not die for a missing metric package
            warnings.warn(f"tracking evaluation and priority refresh skipped, priorities stay as they are: {err}",
                          RuntimeWarning, stacklevel=2)
            scores = {}
        if scores is None:  # stopped mid-episode: no partial scores, priorities untouched
            return {}
        if scores:
            self.emd.update({name: e for name, (e, _) in scores.items()})
            out = {"eval/tracking_emd": float(np.mean([e for e, _ in scores.values()])),
                   "eval/tracking_success": float(np.mean([s for _, s in scores.values()]))}
            if refresh_priorities:
                fill = float(np.median(list(self.emd.values())))
                self.bundle.library.set_priorities_from_emd({n: self.emd.get(n, fill) for n in self.bundle.library.names})
        if self.custom_eval is not None:
            out.update({f"eval/{k}": float(v) for k, v in self.custom_eval(self.agent).items()})
        return out

    def _take_action_stats(self) -> dict[str, float]:
        """Mean |action| and the saturated share of the policy's rollout actions since the last log row."""
        total, saturated, count = self._action_stats
        self._action_stats[:] = 0
        return {"action_abs": total / count, "action_saturated": saturated / count} if count else {}

    def _warn(self, row: dict[str, float]) -> None:
        """Say plainly, once per run and signature, when training heads where failed public runs went."""
        for name, test, message in WARNINGS:
            if name not in self._warned and test(row):
                self._warned.add(name)
                Console(stderr=True).print(f"[yellow]warning at {self.env_steps:,} env steps: {message}[/]")
                with open(self.out / "warnings.txt", "a") as f:
                    f.write(f"{self.env_steps}\t{name}\t{message}\n")

    def _log(self, row: dict[str, float]) -> None:
        if self._writer is None:
            self._writer = _summary_writer(self.out / "tb") or False
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
        """Checkpoint into out/checkpoints/step_XXXXXXXXXX and point out/checkpoints/latest at it."""
        tc = self.cfg.train
        root = self.out / "checkpoints"
        path = root / f"step_{self.env_steps:010d}"
        tensors, meta = self.agent.state()
        tensors.update({"torch_rng": torch.get_rng_state(), "env_qpos": torch.as_tensor(self._env_state()[0]),
                        "env_qvel": torch.as_tensor(self._env_state()[1]), "env_obs": torch.as_tensor(self.obs),
                        "z": self.z.cpu(), "z_age": torch.as_tensor(self.z_age),
                        "env_episode_steps": torch.as_tensor(_episode_counter(self.bundle.env)),
                        "priorities": torch.as_tensor(np.asarray(self.bundle.library.priorities, dtype=np.float64))})
        if torch.cuda.is_available():
            tensors["cuda_rng"] = torch.cuda.get_rng_state()
        py_state = random.getstate()
        meta.update({
            "env_steps": self.env_steps, "updates": self.updates, "episodes": self.episodes,
            "next_priority": _num(self.next_priority), "next_eval": _num(self.next_eval),
            "next_ckpt": _num(self.next_ckpt), "next_log": self.next_log, "emd": self.emd,
            "numpy_rng": self.rng.bit_generator.state, "numpy_global": _np_global_state(),
            "python_rng": [py_state[0], list(py_state[1]), py_state[2]],
            "buffer": {"size": len(self.buffer), "pos": self.buffer.pos},
            "env_rng": self.bundle.env.np_random.bit_generator.state,
        })
        reward, meta["reward_represents"] = self._reward_sample()
        replay = self.buffer.state() if tc.save_buffer else None
        save_checkpoint(path, self.agent.model, self.cfg, trainer_state=(tensors, meta), reward_buffer=reward,
                        replay_buffer=replay)
        tmp = root / ".latest.tmp"
        tmp.write_text(path.name)
        os.replace(tmp, root / "latest")
        self._saved_at = self.env_steps
        for p in prunable_checkpoints(root, tc.keep_checkpoints, tc.keep_every):
            if p != path:
                discard_checkpoint(p)
        return path

    def _checkpoint_path(self) -> Path:
        return self.out / "checkpoints" / f"step_{self.env_steps:010d}"

    def _reward_sample(self) -> tuple[dict[str, np.ndarray] | None, int]:
        """The checkpoint's reward-inference sample and how many transitions it stands for.

        After a resume without the replay buffer, the sample carried over from the checkpoint is merged with the
        new transitions in proportion to what each stands for (as a FIFO buffer would hold them), so a resume
        never leaves reward prompts with less data than the run had."""
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
        old = {k: v[np.sort(rng.choice(carried_n, k_old, replace=False))] for k, v in self._carried.items()}
        if k_new:
            fresh = self.buffer.reward_inference_sample(k_new, rng)
            old = {k: np.concatenate([old[k], fresh[k]]) for k in old}
        return (old if k_old + k_new else None), old_n + new_n

    def close(self) -> None:
        """Remove the memory-mapped replay buffer: scratch space (a resume reads the checkpoint, never this), and
        a file as large as the whole buffer."""
        if self.buffer.memmap_dir is not None:
            self.buffer.data.clear()
            shutil.rmtree(self.buffer.memmap_dir, ignore_errors=True)

    def _env_state(self) -> tuple[np.ndarray, np.ndarray]:
        env = self.bundle.env
        if hasattr(env, "_good_qpos"):
            return np.asarray(env._good_qpos), np.asarray(env._good_qvel)
        return np.asarray(env.qpos), np.asarray(env.qvel)

    def _warm_start(self, src: str | Path) -> None:
        """Start from the weights of any checkpoint, inference-only ones included (the shipped model): networks,
        targets (= the networks) and normaliser; fresh optimisers and an empty replay buffer, which the warm-up
        fills with the loaded policy's own rollouts instead of random actions."""
        from fbcpr.bfm import resolve_checkpoint

        ckpt = load_checkpoint(resolve_checkpoint(src), self.device)
        if ckpt.algorithm != self.cfg.algorithm:
            raise ConfigError(f"algorithm: {self.cfg.algorithm!r} differs from {ckpt.algorithm!r} of the --init-from "
                              f"checkpoint {ckpt.path}")
        theirs = ckpt.config.env.action_mapping if isinstance(ckpt.config, Config) else None
        if theirs is not None and theirs != self.cfg.env.action_mapping:
            raise ConfigError(f"env.action_mapping: {self.cfg.env.action_mapping!r} differs from {theirs!r} of the "
                              f"--init-from checkpoint {ckpt.path}")
        load_state_strict(self.agent.model, ckpt.model.state_dict(), f"{ckpt.path / 'model.safetensors'} (--init-from)")
        self.agent.sync_targets()

    def _resume(self) -> None:
        ckpt = load_checkpoint(latest_checkpoint(self.out / "checkpoints"), self.device)
        load_state_strict(self.agent.model, ckpt.model.state_dict(), str(ckpt.path / "model.safetensors"))
        tensors, meta = ckpt.trainer_state()
        saved_envs = tensors["env_qpos"].shape[0] if "env_qpos" in tensors else self.cfg.train.num_envs
        if saved_envs != self.cfg.train.num_envs:
            raise ConfigError(f"train.num_envs: {self.cfg.train.num_envs}, but {ckpt.path} was saved with "
                              f"{saved_envs} envs; resume with num_envs: {saved_envs} (or start a new run)")
        self.agent.load_state(tensors, meta)
        try:
            self.env_steps, self.updates, self.episodes = meta["env_steps"], meta["updates"], meta["episodes"]
            self.next_priority, self.next_eval = _inf(meta["next_priority"]), _inf(meta["next_eval"])
            self.next_ckpt, self.next_log, self.emd = _inf(meta["next_ckpt"]), meta["next_log"], meta["emd"]
            self.rng.bit_generator.state = meta["numpy_rng"]
            np.random.set_state(tuple(meta["numpy_global"]))
            v, st, gauss = meta["python_rng"]
            random.setstate((v, tuple(st), gauss))
            torch.set_rng_state(tensors["torch_rng"])
            if "cuda_rng" in tensors and torch.cuda.is_available():
                torch.cuda.set_rng_state(tensors["cuda_rng"])
            self.bundle.library.priorities = tensors["priorities"].numpy().copy()
            self.z = tensors["z"].to(self.device)
            self.z_age = tensors["z_age"].numpy().copy()
            self.obs, _ = self.bundle.env.reset(options={"qpos": tensors["env_qpos"].numpy(), "qvel": tensors["env_qvel"].numpy()})
            self.bundle.env.np_random.bit_generator.state = meta["env_rng"]
            _episode_counter(self.bundle.env)[:] = tensors["env_episode_steps"].numpy()
        except KeyError as e:
            raise CheckpointError(f"{ckpt.path}/trainer_state.safetensors: missing entry {e}") from None
        self._saved_at = self.env_steps
        replay = ckpt.replay_buffer()
        if replay is not None:
            self.buffer.load_state(*replay)
            return
        if self.cfg.train.save_buffer:
            raise CheckpointError(f"{ckpt.path}: train.save_buffer is set but the checkpoint has no replay buffer")
        self._carried = ckpt.reward_buffer()
        if self._carried is None:
            lost = "it has no reward-inference sample either: reward prompts will only see the new transitions"
        else:
            self._carried_weight = int(meta.get("reward_represents", meta["buffer"]["size"]))
            lost = (f"its reward-inference sample ({len(self._carried['next_obs']):,} states) is carried over and "
                    "merged with the new transitions")
        self._notice(f"resume: {ckpt.path} has no replay buffer (train.save_buffer: false), so training continues "
                     f"from an empty buffer; {lost}. Set train.save_buffer: true for an exact resume.")

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
        """A yellow line on stderr that is also kept in the run's warnings.txt."""
        Console(stderr=True).print(f"[yellow]{message}[/]", highlight=False)
        with open(self.out / "warnings.txt", "a") as f:
            f.write(f"{self.env_steps}\tnotice\t{message}\n")

    def _metric_text(self) -> str:
        """Compact live metrics for the progress bar, e.g. `u 1,200 fb 3.1 act -12 crit 0.4`."""
        short = {"fb_loss": "fb", "actor_loss": "act", "critic_loss": "crit", "disc_loss": "disc", "reward": "r"}
        parts = [f"{short[k]} {self.last_metrics[k]:.2g}" for k in LIVE_KEYS if k in self.last_metrics]
        return " ".join([f"u {self.updates:,}", *parts])

    def _log_line(self, total: int, rate: float) -> None:
        """One plain progress line (for logs and CI, where the live bar is off)."""
        left = int((total - self.env_steps) / rate) if rate > 0 else None
        eta = "?" if left is None else f"{left // 3600}:{left % 3600 // 60:02d}:{left % 60:02d}"
        print(f"{self.env_steps:,}/{total:,} steps ({100 * self.env_steps / total:.1f}%) {rate:,.0f} steps/s "
              f"eta {eta} | {self._metric_text()}", flush=True)

    @contextmanager
    def _progress(self, total: int) -> Iterator[tuple[Progress | None, Any]]:
        """A rich progress bar over env steps on stderr (or nothing when disabled)."""
        if not self.progress_enabled:
            yield None, None
            return
        with Progress(*progress_columns(), console=Console(stderr=True), transient=False, expand=True) as progress:
            yield progress, progress.add_task("training", total=total, completed=self.env_steps,
                                              metrics=self._metric_text())


def progress_columns() -> list[ProgressColumn]:
    """Training bar columns: steps, rate, elapsed and ETA keep their width; the metrics (a `metrics` task field)
    take what is left and are cut first, so the bar stays readable at 80 columns."""
    def fixed() -> Column:
        return Column(no_wrap=True)

    return [BarColumn(bar_width=10), TextColumn("{task.completed:,}/{task.total:,}", table_column=fixed()),
            _RateColumn(table_column=fixed()), TimeElapsedColumn(table_column=fixed()),
            TextColumn("eta", table_column=fixed()), TimeRemainingColumn(table_column=fixed()),
            TextColumn("{task.fields[metrics]}", table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1))]


class _RateColumn(ProgressColumn):
    """Env steps per second."""

    def render(self, task: Task) -> Text:
        return Text(f"{task.speed:,.0f}/s" if task.speed else "-/s")


#: Bytes per model parameter during training: weights, gradients, two Adam moments and a target copy.
BYTES_PER_PARAMETER = 20


def _memory_bytes(device: torch.device) -> int:
    """Total memory of the device the model trains on (RAM for the CPU)."""
    if device.type == "cuda":
        return int(torch.cuda.get_device_properties(device).total_memory)
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(cfg: Config, nq: int, nv: int, out: Path, device: torch.device) -> bool:
    """Estimate the model's and the replay buffer's memory before allocating either, and raise ConfigError
    naming the key to lower when they cannot fit, instead of an allocation failing (or the OOM killer striking)
    minutes later. Returns whether the buffer is memory-mapped (over train.buffer_memmap_mb)."""
    tc = cfg.train
    with torch.device("meta"):  # shapes only: no memory is allocated
        model = get_method(cfg.algorithm).model(cfg.model)
    params = sum(p.numel() for p in model.parameters())
    need, have = params * BYTES_PER_PARAMETER, _memory_bytes(device)
    if need > have:
        raise ConfigError(f"model: {params / 1e6:,.0f}M parameters need about {need / 2**30:,.1f} GiB to train, "
                          f"more than the {have / 2**30:,.1f} GiB of {device.type} memory; lower model.hidden_dim, "
                          "model.hidden_layers or model.preset")
    specs = transition_specs(cfg.model.obs_dim, cfg.model.action_dim, getattr(model, "z_dim", 0), nq, nv)
    buffer = ReplayBuffer.bytes_needed(tc.buffer_capacity, specs)
    memmap = buffer > tc.buffer_memmap_mb * 2**20
    if memmap:
        folder = next(p for p in (out, *out.absolute().parents) if p.exists())
        free = shutil.disk_usage(folder).free
        if buffer > free:
            raise ConfigError(f"train.buffer_capacity: the memory-mapped replay buffer needs {buffer / 2**30:,.1f} GiB "
                              f"on disk, more than the {free / 2**30:,.1f} GiB free at {folder}")
    else:
        ram = _memory_bytes(torch.device("cpu"))
        if buffer + (need if device.type == "cpu" else 0) > ram:
            raise ConfigError(f"train.buffer_capacity: the replay buffer needs {buffer / 2**30:,.1f} GiB of memory, "
                              f"more than the {ram / 2**30:,.1f} GiB this machine has beside the model; lower it, or "
                              "lower train.buffer_memmap_mb to keep it in a memory-mapped file on disk")
    return memmap


def prunable_checkpoints(root: Path, keep_last: int, keep_every: int) -> list[Path]:
    """Checkpoints that retention removes: all but the last `keep_last`, sparing those at multiples of
    `keep_every` env steps (0: none spared)."""
    steps = sorted(p for p in root.glob("step_*") if p.is_dir())[:-keep_last]
    return [p for p in steps if not (keep_every and int(p.name.split("_")[1]) % keep_every == 0)]


def _summary_writer(path: Path) -> Any:
    """A TensorBoard writer, or None where tensorboard is not installed (metrics.csv is then the only log)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        warnings.warn("tensorboard is not installed: metrics go to metrics.csv only", RuntimeWarning, stacklevel=2)
        return None
    return SummaryWriter(str(path))


def _episode_counter(env: Any) -> np.ndarray:
    """The env's per-env step-in-episode counters (so a resumed run truncates episodes at the same steps)."""
    counter = getattr(env, "steps", getattr(env, "_steps", None))
    if not isinstance(counter, np.ndarray):
        raise TypeError(f"{type(env).__name__}: no per-env episode step counter to save")
    return counter


def _num(x: float) -> float | None:
    return None if math.isinf(x) else x


def _inf(x: float | None) -> float:
    return math.inf if x is None else x


def _np_global_state() -> list[Any]:
    name, keys, pos, has_gauss, cached = np.random.get_state()
    return [name, keys.tolist(), int(pos), int(has_gauss), float(cached)]


def train(cfg: Config, out_dir: str | Path, resume: bool = False, progress: bool = True,
          init_from: str | Path | None = None) -> dict[str, Any]:
    """Build a Trainer and run it to the end (or until interrupted); `init_from` warm-starts a new run."""
    trainer = Trainer(cfg, out_dir, resume=resume, progress=progress, init_from=init_from)
    try:
        summary = trainer.run()
    finally:
        trainer.close()
    (Path(out_dir) / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return summary


def checkpoint_env_steps(run_dir: str | Path) -> int:
    """Env steps of a run directory's latest checkpoint (read from its trainer-state header only)."""
    path = latest_checkpoint(Path(run_dir) / "checkpoints")
    try:
        return int(read_trainer_meta(path)["env_steps"])
    except KeyError:
        raise CheckpointError(f"{path}: trainer state without env_steps") from None
