"""Any checkpoint as an evaluation agent: a `BFM` for a prompt-able method, an offline model of the registry
(NPMP) as its own agent, a `SingleTaskAgent` for a single-task method; and the floors by name."""
from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np

from fbcpr.core.checkpoint import MANIFEST_FILE, load_checkpoint, read_manifest
from fbcpr.core.registry import OFFLINE_MODELS, get_method, load
from fbcpr.eval.agents import Agent, RandomAgent, SingleTaskAgent, ZeroAgent
from fbcpr.inference.bfm import BFM, resolve_checkpoint
from fbcpr.methods.fb_cpr.model import FBCPRModel


def make_agent(spec: str, seed: int = 0, device: str = "cpu") -> Agent:
    """`random`, `zero`, or a checkpoint path / hub id: a `fbcpr.BFM` for FB-CPR, an `NPMPAgent` for an NPMP, a
    `SingleTaskAgent` otherwise."""
    if spec == "random":
        return RandomAgent(seed)
    if spec == "zero":
        return ZeroAgent()
    path = resolve_checkpoint(spec)
    npmp = _offline_agent(path, spec, device)
    if npmp is not None:
        return npmp
    ckpt = load_checkpoint(path, device)
    if get_method(ckpt.algorithm).promptable:
        # a prompt-able method's model is what a BFM wraps
        return BFM(cast(FBCPRModel, ckpt.model), ckpt.config, source=spec, checkpoint=ckpt)
    return SingleTaskAgent(ckpt.model, ckpt.config, spec)


def live_agent(model: Any, config: Any, reward_buffer: dict[str, np.ndarray] | None) -> Agent:
    """The agent of a model still in training, as `make_agent` would give it from a checkpoint of the run: a BFM
    prompted through `reward_buffer` (the run's reward-inference sample), or a single-task agent on its task."""

    if get_method(config.algorithm).promptable:
        return BFM(model, config, reward_buffer=reward_buffer, source="training")
    return SingleTaskAgent(model, config, "training")


def load_tracker(spec: str, device: str = "cpu") -> Agent:
    """A model that tracks a clip with one z per step (`track_z`, then `act`): a `BFM`, or an `NPMPAgent` whose
    encoder gives the z's. Any other checkpoint is refused by `BFM.load` with its reason."""
    path = resolve_checkpoint(spec)
    npmp = _offline_agent(path, spec, device)
    return npmp if npmp is not None else BFM.load(path, device=device)


def _offline_agent(path: Path, spec: str, device: str) -> Agent | None:
    """The agent of a checkpoint directory whose manifest records an offline model of the registry (NPMP), else
    None."""
    file = Path(path) / MANIFEST_FILE
    algorithm = read_manifest(file).get("algorithm") if file.is_file() else None
    if algorithm not in OFFLINE_MODELS:
        return None
    return load(OFFLINE_MODELS[algorithm])(path, device, name=spec)
