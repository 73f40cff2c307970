"""VIRLReward: the recurrent Siamese comparator as an `ImitationReward` for TD3 (states or video).

How the comparator gets sequences: the protocol's reward sees replay transitions (s, s'), so the agent asks
the replay buffer for each transition's `history` (the episode's states before s, `ReplayBuffer.sample(history=)`,
walking back one env's rows); the agent's sequence is history + s' (seq_length states ending at s'). The
demonstration is not played alongside the agent (no phase in our env), so the reward aligns in time the way the
paper's App. 7.3 describes: the distance is to the closest of a bank of demonstration windows,

    d = min_j  seq_w * ||h_a - h_j|| + frame_w * ||e_a,last - e_j,last||,     reward = exp(-width * d^2)  (App. 7.7)

The comparator keeps training online (one step per TD3 update, as AMP's discriminator): on the demonstration
windows the trainer passes, the agent's own replay sequences (negatives), time manipulations of the demonstration
and, with `multitask`, windows of other clips (`fbcpr.rewards.virl.losses`).

Video input: the toy's states are rasterised as they come (batched torch). The humanoid's frames are rendered once
per collected transition (`frame_size`: the collector renders s' the plain way, the replay buffer keeps it as uint8)
and the agent passes the stored frames of history + s'; the demonstration video is the env's clips rendered the same
way at start, or a folder of frames (`demo_frames`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from fbcpr.core.errors import ConfigError
from fbcpr.nn.normalizer import RunningNormalizer
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state
from fbcpr.rewards.virl.config import VIRLConfig
from fbcpr.rewards.virl.frames import load_frames, rasterize_points, render_clip
from fbcpr.rewards.virl.losses import make_pairs, virl_loss
from fbcpr.rewards.virl.model import Comparator

TOY_OBS_DIM = 2  # the point mass: the env whose states the video path rasterises; other envs' frames are stored


def load_clips(spec: str) -> list[np.ndarray]:
    """Observation sequences (T, obs_dim) of `agent.virl.multitask`: a clip file or folder, or toy demo names."""
    path = Path(spec).expanduser()
    if path.exists():
        from motions.library import MotionLibrary

        library = MotionLibrary.load([path] if path.is_file() else path)
        return [np.asarray(c.obs, dtype=np.float32) for c in library.clips]
    from fbcpr.envs.toy import demo_paths

    demos = demo_paths()
    names = list(demos) if spec == "synthetic" else [n.strip() for n in spec.split(",")]
    unknown = [n for n in names if n not in demos]
    if unknown:
        raise ConfigError(f"agent.virl.multitask: {unknown[0]!r} is neither a clip file/folder nor a toy "
                          f"demonstration ({sorted(demos)})")
    return [demos[n] for n in names]


def windows_of(clip: Tensor, length: int) -> Tensor:
    """Every window of `length` consecutive frames of a clip (T, *frame): (T - length + 1, length, *frame)."""
    if clip.shape[0] < length:
        raise ValueError(f"a demonstration of {clip.shape[0]} frames is shorter than agent.virl.seq_length={length}")
    return clip.unfold(0, length, 1).movedim(-1, 1)


class VIRLReward:
    """The comparator, its state normaliser, Adam optimiser, random stream and bank of demonstration windows."""

    def __init__(self, obs_dim: int, cfg: VIRLConfig, device: str | torch.device = "cpu", seed: int = 0,
                 library: Any = None) -> None:
        """`library` is not kept: the demonstration windows come with each `fit`, other clips from `cfg.multitask`."""
        stored = cfg.input == "video" and obs_dim != TOY_OBS_DIM  # the humanoid: frames rendered at collection
        if stored and cfg.multitask:
            raise ConfigError("agent.virl.multitask: other clips are state sequences; with input: video on the "
                              "humanoid the comparator's data is the demonstration video and the agent's frames: "
                              "leave multitask out")
        if stored and cfg.demo_frames is None and not getattr(library, "clips", None):
            raise ConfigError("agent.virl.input: video on the humanoid needs demonstration clips to render (the env's "
                              "motions) or agent.virl.demo_frames")
        self.cfg, self.device, self.obs_dim = cfg, torch.device(device), obs_dim
        self.frame_size = cfg.image_size if stored else 0  # the agent asks the collector for frames of this side
        self.history = cfg.seq_length - 1          # states before s the agent asks the replay buffer for
        with torch.random.fork_rng(devices=[]):  # its own initialisation, leaving the caller's stream alone
            torch.manual_seed(seed + 2)
            self.model = Comparator(obs_dim, cfg).to(self.device)
        self.normalizer = RunningNormalizer(obs_dim).to(self.device)
        self.step_normalizer = RunningNormalizer(obs_dim).to(self.device)  # of s_t - s_{t-1} (cfg.motion)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=cfg.lr)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed + 2)  # not the agent's stream, nor AMP's
        self.frames: Tensor | None = None     # a video demonstration's windows (input: video with demo_frames)
        if cfg.demo_frames is not None:
            clip = torch.as_tensor(load_frames(cfg.demo_frames, cfg.image_size), device=self.device)
            self.frames = self._with_motion(windows_of(clip, cfg.seq_length))
        elif stored:  # every window of each clip, rendered as the collector renders the agent's frames
            self.frames = torch.cat([self._with_motion(windows_of(torch.as_tensor(
                render_clip(np.asarray(c.qpos), cfg.image_size), device=self.device), cfg.seq_length))
                for c in library.clips])
        width = (cfg.seq_length, obs_dim)
        self.bank = torch.zeros(cfg.bank_size, *width, device=self.device)  # raw demonstration windows (FIFO)
        self.bank_pos = self.bank_fill = 0
        self.others = ([torch.as_tensor(c, device=self.device) for c in load_clips(cfg.multitask)]
                       if cfg.multitask else [])
        self._others_checked = False

    # ------------------------------------------------------------------------------------------- inputs
    def _inputs(self, raw: Tensor) -> Tensor:
        """Comparator inputs of raw state sequences (N, L, obs_dim): normalised states, or rendered frames for
        video, each with its normalised change from the previous step when cfg.motion (zero for the first)."""
        if self.cfg.input == "video":
            return self._with_motion(rasterize_points(raw[..., :2], self.cfg.image_size))
        x = self.normalizer(raw)
        if not self.cfg.motion:
            return x
        return torch.cat([x, self.step_normalizer(torch.diff(raw, dim=1, prepend=raw[:, :1]))], -1)

    def _with_motion(self, frames: Tensor) -> Tensor:
        """Grey frames (N, L, S, S) as channels (N, L, C, S, S): the frame, and with cfg.motion its difference
        from the previous frame (a small step of a dot is invisible to a conv net in one frame)."""
        if not self.cfg.motion:
            return frames[:, :, None]
        return torch.stack([frames, torch.diff(frames, dim=1, prepend=frames[:, :1])], 2)

    def _agent_sequences(self, obs: Tensor, next_obs: Tensor, history: Tensor | None) -> Tensor:
        """history + s' (the last seq_length states), or (s, s') when no history is given."""
        seq = torch.cat([history, next_obs[:, None]], 1) if history is not None else torch.stack([obs, next_obs], 1)
        return seq[:, -self.cfg.seq_length:].to(self.device, torch.float32)

    def _agent_inputs(self, obs: Tensor, next_obs: Tensor, history: Tensor | None, frames: Tensor | None) -> Tensor:
        """Comparator inputs of the agent's sequences: its stored frames (uint8, history + s') for the humanoid's
        video, else its states (history + s') as `_inputs` makes them."""
        if not self.frame_size:
            return self._inputs(self._agent_sequences(obs, next_obs, history))
        if frames is None:
            raise ValueError("VIRL video on the humanoid reads each transition's stored frames (batch['frames']); "
                             "the replay buffer was sampled without them")
        return self._with_motion(frames[:, -self.cfg.seq_length:].to(self.device, torch.float32) / 255.0)

    def _demo_windows(self, expert_windows: Tensor) -> Tensor:
        """This step's demonstration windows as comparator inputs (and the bank refreshed with them)."""
        L, n = self.cfg.seq_length, expert_windows.shape[0]
        if self.frames is not None:
            pick = torch.randint(len(self.frames), (n,), generator=self.generator, device=self.device)
            return self.frames[pick]
        if expert_windows.shape[1] < L:
            raise ValueError(f"agent.seq_length ({expert_windows.shape[1]}) must be >= agent.virl.seq_length ({L})")
        raw = expert_windows[:, -L:].to(self.device, torch.float32)
        idx = (self.bank_pos + torch.arange(n, device=self.device)) % self.cfg.bank_size
        self.bank[idx] = raw
        self.bank_pos = int((self.bank_pos + n) % self.cfg.bank_size)
        self.bank_fill = min(self.bank_fill + n, self.cfg.bank_size)
        return raw

    def _other_windows(self, n: int, demo_state: Tensor | None) -> tuple[Tensor | None, Tensor | None]:
        """n raw windows of the multi-task clips and their clip ids; clips holding the demonstration's state
        `demo_state` (a state demonstration's first frame) are left out, so the demo is never its own negative."""
        if not self._others_checked and demo_state is not None:
            self.others = [c for c in self.others if not (c - demo_state).abs().amax(-1).lt(1e-5).any()]
            self._others_checked = True
        if not self.others:
            return None, None
        L = self.cfg.seq_length
        ids = torch.randint(len(self.others), (n,), generator=self.generator, device=self.device)
        lengths = torch.tensor([len(c) for c in self.others], device=self.device)
        start = (torch.rand(n, generator=self.generator, device=self.device) * (lengths[ids] - L + 1)).long()
        flat = torch.cat(self.others)
        offsets = torch.cumsum(lengths, 0) - lengths
        return flat[(offsets[ids] + start)[:, None] + torch.arange(L, device=self.device)], ids

    # ------------------------------------------------------------------------------------------- protocol
    def fit(self, expert_windows: Tensor, batch: dict[str, Tensor]) -> dict[str, float]:
        """One comparator step on demonstration windows vs the batch's agent sequences (and other clips)."""
        raw_demo = self._demo_windows(expert_windows)
        n = raw_demo.shape[0]
        if batch["obs"].shape[0] < n:
            raise ValueError(f"VIRL needs at least {n} agent sequences per batch, got {batch['obs'].shape[0]}")
        others, ids = self._other_windows(n, raw_demo[0, 0] if self.frames is None else None)
        if self.frame_size:
            frames = batch.get("frames")
            agent_in = self._agent_inputs(batch["obs"], batch["next_obs"], None, None if frames is None else frames[:n])
        else:
            agent = self._agent_sequences(batch["obs"], batch["next_obs"], batch.get("history"))[:n]
            if self.cfg.input == "state":
                states = [agent, raw_demo] + ([others] if others is not None else [])
                self.normalizer.update(torch.cat([s.reshape(-1, self.obs_dim) for s in states]))
                self.step_normalizer.update(torch.cat([torch.diff(s, dim=1).reshape(-1, self.obs_dim)
                                                       for s in states]))
            agent_in = self._inputs(agent)
        demo = raw_demo if self.frames is not None else self._inputs(raw_demo)
        pairs = make_pairs(demo, agent_in, None if others is None else self._inputs(others), ids,
                           self.cfg.noise, self.generator)
        c = self.cfg
        loss, parts = virl_loss(self.model, pairs, c.margin,
                                (c.seq_loss_weight, c.frame_loss_weight, c.seq_ae_weight, c.frame_ae_weight))
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        values = torch.stack([v.detach() for v in parts.values()]).tolist()
        return {f"virl/{k}": v for k, v in zip(parts, values)}

    @torch.no_grad()
    def distance(self, seq: Tensor) -> Tensor:
        """(N,) blended distance of raw agent state sequences (N, T, obs_dim) to their closest demonstration window."""
        return self._closest(self._inputs(seq.to(self.device, torch.float32)))

    def _closest(self, x: Tensor) -> Tensor:
        """(N,) blended distance of comparator inputs (N, L, *frame) to their closest demonstration window."""
        bank = self.frames if self.frames is not None else self._inputs(self.bank[:self.bank_fill])
        if len(bank) == 0:
            raise RuntimeError("VIRLReward: no demonstration windows yet (call fit first)")
        e, h = self.model.encode(x)
        eb, hb = self.model.encode(bank)
        d = (self.cfg.seq_reward_weight * torch.cdist(h, hb)
             + self.cfg.frame_reward_weight * torch.cdist(e[:, -1], eb[:, -1]))
        return d.min(1).values

    @torch.no_grad()
    def reward(self, obs: Tensor, next_obs: Tensor, z: Tensor | None = None, history: Tensor | None = None,
               frames: Tensor | None = None) -> Tensor:
        """exp(-width * d^2) of the agent's sequences (history + s', or their stored frames); z is not used."""
        d = self._closest(self._agent_inputs(obs.to(self.device), next_obs.to(self.device), history, frames))
        return torch.exp(-self.cfg.reward_width * d.square())

    # ------------------------------------------------------------------------------------------- state
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        tensors = {f"model.{k}": v for k, v in self.model.state_dict().items()}
        tensors.update({f"normalizer.{k}": v for k, v in self.normalizer.state_dict().items()})
        tensors.update({f"step_normalizer.{k}": v for k, v in self.step_normalizer.state_dict().items()})
        tensors["bank"] = self.bank.clone()
        meta = {"optimizer": optimizer_state(self.optimizer, "optim", tensors), "bank_pos": self.bank_pos,
                "bank_fill": self.bank_fill}
        tensors["generator"] = self.generator.get_state()
        return tensors, meta

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        from fbcpr.core.checkpoint import CheckpointError, load_state_strict

        for name, module in (("model", self.model), ("normalizer", self.normalizer),
                             ("step_normalizer", self.step_normalizer)):
            part = {k[len(name) + 1:]: v for k, v in tensors.items() if k.startswith(f"{name}.")}
            load_state_strict(module, part, f"trainer_state.safetensors (VIRL {name})")
        if tensors["bank"].shape != self.bank.shape:
            raise CheckpointError(f"trainer_state.safetensors (VIRL bank): shape {tuple(tensors['bank'].shape)}, "
                                  f"expected {tuple(self.bank.shape)}")
        self.bank.copy_(tensors["bank"])
        self.bank_pos, self.bank_fill = int(meta["bank_pos"]), int(meta["bank_fill"])
        load_optimizer_state(self.optimizer, "optim", meta["optimizer"], tensors)
        self.generator.set_state(tensors["generator"])
