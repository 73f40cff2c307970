"""NPMP checkpoints: the layout and guarantees of `fbcpr.core.checkpoint` (safetensors + JSON, sha256 manifest,
atomic replacement, never unpickled), with `npmp.json` for the model's config and provenance in place of the
run config, and `algorithm: npmp` in the manifest, which is how a loader tells an NPMP checkpoint apart."""
from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from fbcpr.apps.npmp.config import npmp_config
from fbcpr.apps.npmp.model import NPMPModel
from fbcpr.core.checkpoint import (
    MANIFEST_FILE,
    MODEL_FILE,
    TRAINER_FILE,
    CheckpointError,
    check_recorded_sizes,
    load_state_strict,
    read_manifest,
    read_tensors,
    seal,
    staging_dir,
    verify,
    write_tensors,
)
from fbcpr.core.errors import ConfigError
from fbcpr.core.schema import config_to_dict

ALGORITHM = "npmp"
INFO_FILE = "npmp.json"


@dataclass
class NPMPCheckpoint:
    """A loaded NPMP checkpoint: the model, what npmp.json records (expert, method, step, ...), the manifest."""

    path: Path
    model: NPMPModel
    info: dict[str, Any]
    manifest: dict[str, Any] = field(default_factory=dict)

    def trainer_state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        if TRAINER_FILE not in self.manifest.get("files", {}):
            raise CheckpointError(f"{self.path}: no {TRAINER_FILE} (cannot resume distillation from it)")
        return read_tensors(self.path, TRAINER_FILE, self.manifest)


def is_npmp_checkpoint(path: str | Path) -> bool:
    """Whether a checkpoint directory's manifest records an NPMP model."""
    file = Path(path) / MANIFEST_FILE
    return file.is_file() and read_manifest(file).get("algorithm") == ALGORITHM


def save_npmp(path: str | Path, model: NPMPModel, info: dict[str, Any],
              trainer_state: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None) -> Path:
    """Write a checkpoint directory atomically (the previous one at `path` stays readable until the swap)."""
    path = Path(path)
    tmp = staging_dir(path)
    try:
        write_tensors(tmp / MODEL_FILE, dict(model.state_dict()))
        if trainer_state is not None:
            write_tensors(tmp / TRAINER_FILE, *trainer_state)
        record = {**info, "config": config_to_dict(model.cfg), "obs_dim": model.obs_dim, "action_dim": model.action_dim}
        (tmp / INFO_FILE).write_text(json.dumps(record, indent=1))
        seal(tmp, path, ALGORITHM, {"obs_dim": model.obs_dim, "action_dim": model.action_dim, "z_dim": model.z_dim})
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def load_npmp(path: str | Path, device: str | torch.device = "cpu") -> NPMPCheckpoint:
    """Load and verify an NPMP checkpoint directory; CheckpointError naming the file and the problem."""
    path = Path(path)
    manifest = read_manifest(path / MANIFEST_FILE)
    if manifest.get("algorithm") != ALGORITHM:
        raise CheckpointError(f"{path}: holds a {manifest.get('algorithm', 'fb_cpr')!r} checkpoint, not an NPMP model")
    verify(path / INFO_FILE, manifest)
    try:
        info = json.loads((path / INFO_FILE).read_text())
        cfg = npmp_config(info["config"])
        dims = int(info["obs_dim"]), int(info["action_dim"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, ConfigError) as err:
        raise CheckpointError(f"{path / INFO_FILE}: invalid ({type(err).__name__}: {err})") from None
    model = NPMPModel(cfg, *dims)
    tensors, _ = read_tensors(path, MODEL_FILE, manifest)
    load_state_strict(model, tensors, str(path / MODEL_FILE))
    check_recorded_sizes(path, manifest, {"obs_dim": model.obs_dim, "action_dim": model.action_dim,
                                          "z_dim": model.z_dim})
    return NPMPCheckpoint(path=path, model=model.to(device).eval(), info=info, manifest=manifest)
