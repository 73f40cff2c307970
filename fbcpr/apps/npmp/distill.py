"""Distillation: fit the NPMP to expert data with the beta-weighted objective (paper Eq. 3; LFPC: Eq. 9).

One sample is a subsequence of `seq_length` steps of an expert episode plus the K frames after it. Per step t the
encoder sees x_t = [s_t..s_{t+K}] and z_{t-1} (z_{-1} ~ N(0, I), the prior's marginal, at a subsequence start),
z_t is drawn from q by reparametrisation, and the loss is

    -log pi(a_t | s_t, z_t) + beta KL(q(z_t | z_{t-1}, x_t) || N(alpha z_{t-1}, (1 - alpha^2) I))

averaged over steps, where -log pi is ||a_t - mu(s_t, z_t)||^2 / (2 std^2) (fixed std, the constant dropped).
LFPC draws a fresh perturbation ds ~ N(0, diag(perturb_std^2)) for every frame, feeds s + ds to encoder and
decoder and uses the linear-feedback target a* + J ds (clipped to the action range [-1, 1]).
Steps past an episode's end repeat its last frame and are masked out of the loss.
"""
from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from fbcpr.apps.npmp.checkpoint import load_npmp, save_npmp
from fbcpr.apps.npmp.config import NPMPConfig
from fbcpr.apps.npmp.data import ExpertData
from fbcpr.apps.npmp.model import NPMPModel, kl_to_prior
from fbcpr.core.checkpoint import CheckpointError, discard_checkpoint, latest_checkpoint, write_pointer
from fbcpr.core.errors import InputError
from fbcpr.nn.optim_state import load_optimizer_state, optimizer_state
from fbcpr.train.trainer import STOP_SIGNALS

CHECKPOINTS = "checkpoints"


class Distiller:
    """The model, its Adam optimiser and the sampling generator: one `update` is one gradient step."""

    def __init__(self, model: NPMPModel, data: ExpertData) -> None:
        if data.obs.shape[1] != model.obs_dim or data.action.shape[1] != model.action_dim:
            raise InputError(f"expert data has obs/action dims {data.obs.shape[1]}/{data.action.shape[1]}, the model "
                             f"{model.obs_dim}/{model.action_dim}")
        self.model, self.data, self.cfg = model, data, model.cfg
        self.opt = torch.optim.Adam(model.parameters(), lr=self.cfg.lr)
        self.gen = torch.Generator().manual_seed(self.cfg.seed)
        self.steps = 0

    def batch(self) -> tuple[Tensor, Tensor, Tensor]:
        """Raw frames (B, L+K, obs_dim), action targets (B, L, action_dim) and the step mask (B, L)."""
        d, L, K, B = self.data, self.cfg.seq_length, self.cfg.horizon, self.cfg.batch_size
        lengths = d.lengths
        ep = torch.multinomial(lengths.double(), B, replacement=True, generator=self.gen)  # by length: uniform steps
        n = lengths[ep]
        off = (torch.rand(B, generator=self.gen, dtype=torch.float64) * (n - L).clamp(min=0).add(1)).long()
        rel = off[:, None] + torch.arange(L + K)
        idx = d.episode_start[ep][:, None] + torch.minimum(rel, n[:, None] - 1)
        frames, targets, mask = d.obs[idx], d.action[idx[:, :L]], rel[:, :L] < n[:, None]
        if d.method == "lfpc":
            assert d.jacobian is not None  # LFPC data is checked to hold its Jacobians
            delta = torch.randn(frames.shape, generator=self.gen) * d.perturb_std
            frames = frames + delta
            feedback = torch.einsum("blad,bld->bla", d.jacobian[idx[:, :L]].float(), delta[:, :L])
            targets = (targets + feedback).clamp(-1.0, 1.0)
        return frames, targets, mask

    def losses(self, frames: Tensor, targets: Tensor, mask: Tensor) -> dict[str, Tensor]:
        """Masked means over steps of the objective and its parts (nll, kl) and the action MSE."""
        m, L, K = self.model, targets.shape[1], self.cfg.horizon
        n = m.obs_normalizer(frames)
        windows = n[:, torch.arange(L)[:, None] + torch.arange(K + 1)]  # (B, L, K+1, obs)
        z = torch.randn(n.shape[0], m.z_dim, generator=self.gen)
        zs, kls = [], []
        for t in range(L):  # the latent recursion is sequential; everything else is batched
            mean, log_std = m.posterior(z, windows[:, t])
            kls.append(kl_to_prior(mean, log_std, z, self.cfg.alpha))
            z = mean + torch.exp(log_std) * torch.randn(mean.shape, generator=self.gen)
            zs.append(z)
        actions = m.decode(n[:, :L], torch.stack(zs, 1))
        sq = (actions - targets).square().sum(-1)
        w = mask.float() / mask.sum()
        nll = (w * sq).sum() / (2.0 * self.cfg.action_std**2)
        kl = (w * torch.stack(kls, 1)).sum()
        return {"loss": nll + self.cfg.beta * kl, "nll": nll, "kl": kl, "mse": (w * sq).sum() / targets.shape[-1]}

    def update(self) -> dict[str, float]:
        out = self.losses(*self.batch())
        self.opt.zero_grad(set_to_none=True)
        out["loss"].backward()
        self.opt.step()
        self.steps += 1
        return {k: float(v.detach()) for k, v in out.items()}

    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        tensors: dict[str, Tensor] = {"generator": self.gen.get_state()}
        return tensors, {"steps": self.steps, "optimizer": optimizer_state(self.opt, "adam", tensors)}

    def load_state(self, tensors: dict[str, Tensor], meta: dict[str, Any]) -> None:
        try:
            load_optimizer_state(self.opt, "adam", meta["optimizer"], tensors)
            self.gen.set_state(tensors["generator"])
            self.steps = int(meta["steps"])
        except (KeyError, ValueError, TypeError, RuntimeError) as err:
            raise CheckpointError(f"distillation state does not fit this model ({type(err).__name__}: {err})") from None


def distill(out: Path, data: ExpertData, cfg: NPMPConfig, steps: int, info: dict[str, Any], resume: bool = False,
            checkpoint_every: int = 500,
            on_update: Callable[[int, dict[str, float]], None] | None = None) -> tuple[Path, int]:
    """Train until `steps` gradient steps in total, checkpointing into out/checkpoints (latest only) every
    `checkpoint_every` steps and at the end (also when a stop signal ends it early); `resume` continues from the
    latest checkpoint there (its config wins). Returns the final checkpoint and the step count reached."""
    root = Path(out) / CHECKPOINTS
    if resume:
        ckpt = load_npmp(latest_checkpoint(root))
        distiller = Distiller(ckpt.model, data)
        distiller.load_state(*ckpt.trainer_state())
        info = {k: v for k, v in ckpt.info.items() if k not in ("config", "obs_dim", "action_dim", "metrics", "steps")}
    else:
        if (root / "latest").exists():
            raise InputError(f"--out: {out} already holds an NPMP run; pass --resume to continue it or choose another "
                                  "--out")
        model = NPMPModel(cfg, data.obs.shape[1], data.action.shape[1])
        model.obs_normalizer.update(data.obs)  # fixed statistics of the expert states
        distiller = Distiller(model, data)
    last = latest_checkpoint(root) if resume else None
    metrics: dict[str, float] = {}
    with _stop_on_signal() as stopped:
        while distiller.steps < steps and not stopped():
            metrics = distiller.update()
            if on_update is not None:
                on_update(distiller.steps, metrics)
            if distiller.steps % checkpoint_every == 0 or distiller.steps == steps:
                last = _save(root, distiller, {**info, "metrics": metrics})
    if last is None or last.name != _step_name(distiller.steps):  # stopped between checkpoints
        last = _save(root, distiller, {**info, "metrics": metrics})
    return last, distiller.steps


@contextmanager
def _stop_on_signal() -> Iterator[Callable[[], bool]]:
    """The trainer's stop signals (SIGINT, SIGTERM, SIGHUP) end distillation after the current gradient step, with a
    final checkpoint; a second one aborts at once (KeyboardInterrupt), the last checkpoint staying intact."""
    flag = {"stop": False}

    def handler(signum: int, frame: Any) -> None:
        if flag["stop"]:
            raise KeyboardInterrupt
        flag["stop"] = True

    old = {}
    for sig in STOP_SIGNALS:
        try:
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread: no handlers, Ctrl-C raises as usual
            pass
    try:
        yield lambda: flag["stop"]
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _step_name(steps: int) -> str:
    return f"step_{steps:08d}"


def _save(root: Path, distiller: Distiller, info: dict[str, Any]) -> Path:
    """Write step_XXXXXXXX, point `latest` at it, then drop the previous one."""
    previous = latest_checkpoint(root) if (root / "latest").exists() else None
    path = save_npmp(root / _step_name(distiller.steps), distiller.model, {**info, "steps": distiller.steps},
                     distiller.state())
    write_pointer(root, "latest", path.name)
    if previous is not None and previous != path and previous.exists():
        discard_checkpoint(previous)
    return path
