"""Checkpoint directories: safetensors + YAML + JSON only, written atomically, verified on load.

Layout of a checkpoint directory:
    model.safetensors           model weights and normalizer statistics
    config.yaml                 the run config (or just the `model:` section)
    manifest.json               format version, method (`algorithm`), library versions, sha256 and shapes of every file
    trainer_state.safetensors   optional: target nets, optimizer moments; JSON scalars/counters/RNG in its header
    reward_buffer.safetensors   optional: next_obs, qpos, qvel subsample for reward prompts (exports may store
                                the states alone: next_obs is rebuilt from them on load, the env kind's observer
                                in `fbcpr.core.registry.ENVS`)
    reward_prompts.safetensors  optional: the reward prompts (z) of the named tasks, inferred at export from more
                                states than reward_buffer keeps (`fbcpr.inference.reward_prompts`)
    replay_buffer.safetensors   optional: the whole replay buffer (exact resume)

`save_checkpoint` writes everything into a temporary sibling directory and moves it into place with
renames, so an interrupted save leaves the previous checkpoint readable. `load_checkpoint` never
unpickles: it only reads safetensors, JSON and `yaml.safe_load`. The method (`fbcpr.core.registry`) is recorded in
config.yaml and the manifest and picks the model class on load; a checkpoint that records none is FB-CPR.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import time
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import safetensors
import torch
import yaml
from safetensors.torch import load_file, save_file

import fbcpr
from fbcpr.core.config import config_from_dict, data_relative_config, expand_data_paths, model_config_from_dict
from fbcpr.core.errors import ConfigError, FBCPRError
from fbcpr.core.registry import DEFAULT_ALGORITHM, METHODS, env_kind, get_method
from fbcpr.core.schema import Config, ModelConfig, config_to_dict, env_of
from humanoid_env.actions import LEGACY_ACTION_MAPPING

FORMAT = "fbcpr-checkpoint"
FORMAT_VERSION = 1
MODEL_FILE, CONFIG_FILE, MANIFEST_FILE = "model.safetensors", "config.yaml", "manifest.json"
TRAINER_FILE, REWARD_FILE = "trainer_state.safetensors", "reward_buffer.safetensors"
REPLAY_FILE = "replay_buffer.safetensors"
PROMPTS_FILE = "reward_prompts.safetensors"
REWARD_KEYS = ("next_obs", "qpos", "qvel")
STATE_KEYS = ("qpos", "qvel")
#: Most states a states-only reward sample may hold: loading rebuilds each one's observation (~25 µs a state).
MAX_REBUILT_STATES = 500_000
_META_KEY = "fbcpr_json"
#: The pointer files a run's checkpoints folder may hold: each names one checkpoint folder beside it.
POINTERS = ("latest", "best")


class CheckpointError(FBCPRError, RuntimeError):
    """A checkpoint that is missing, corrupted or does not match its config; the message names the problem."""


@dataclass
class Checkpoint:
    """A loaded checkpoint: the model (of the method it records), its config, and lazy access to the optional files."""

    path: Path
    model: torch.nn.Module
    config: Config | ModelConfig
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def algorithm(self) -> str:
        return self.config.algorithm if isinstance(self.config, Config) else DEFAULT_ALGORITHM

    @property
    def model_config(self) -> ModelConfig:
        return self.config.model if isinstance(self.config, Config) else self.config

    def has(self, name: str) -> bool:
        return name in self.manifest.get("files", {})

    def trainer_state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """(tensors, json metadata) of trainer_state.safetensors."""
        if not self.has(TRAINER_FILE):
            raise CheckpointError(f"{self.path}: no {TRAINER_FILE} (an inference-only checkpoint cannot be resumed)")
        return read_tensors(self.path, TRAINER_FILE, self.manifest)

    def reward_buffer(self) -> dict[str, np.ndarray] | None:
        """The reward-inference buffer (next_obs, qpos, qvel) as numpy arrays, or None if absent; next_obs is
        rebuilt from the states when the file stores states only."""
        if not self.has(REWARD_FILE):
            return None
        tensors, _ = read_tensors(self.path, REWARD_FILE, self.manifest)
        states_only = "next_obs" not in tensors
        missing = [k for k in (STATE_KEYS if states_only else REWARD_KEYS) if k not in tensors]
        if missing:
            raise CheckpointError(f"{self.path / REWARD_FILE}: missing tensors {missing}")
        buf = {k: tensors[k].float().numpy() for k in STATE_KEYS}  # compact exports store float16
        if not states_only:
            return {"next_obs": tensors["next_obs"].float().numpy(), **buf}
        observer = env_kind(env_of(self.config).name).observer()
        if buf["qpos"].ndim != 2 or buf["qvel"].ndim != 2 or len(buf["qpos"]) != len(buf["qvel"]):
            raise CheckpointError(f"{self.path / REWARD_FILE}: qpos {tuple(buf['qpos'].shape)} and qvel "
                                  f"{tuple(buf['qvel'].shape)} are not one row per state")
        if len(buf["qpos"]) > MAX_REBUILT_STATES:
            raise CheckpointError(f"{self.path / REWARD_FILE}: {len(buf['qpos']):,} states without observations; "
                                  f"loading rebuilds at most {MAX_REBUILT_STATES:,} (export fewer: --reward-samples)")
        try:
            return {"next_obs": observer(buf["qpos"], buf["qvel"]), **buf}
        except ValueError as e:  # a state of the wrong width for the env
            raise CheckpointError(f"{self.path / REWARD_FILE}: {e}") from None

    def reward_prompts(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]] | None:
        """(task name -> z, metadata) of reward_prompts.safetensors, or None if absent; `fbcpr.inference.reward_prompts`
        checks them against the model."""
        return read_tensors(self.path, PROMPTS_FILE, self.manifest) if self.has(PROMPTS_FILE) else None

    def replay_buffer(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]] | None:
        return read_tensors(self.path, REPLAY_FILE, self.manifest) if self.has(REPLAY_FILE) else None


def sha256(path: Path) -> str:
    """Hex SHA-256 of a file, as the manifest records it (corruption shows up on load)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def umask_permissions(path: str | Path) -> None:
    """Give a file the permissions the umask gives a new file (0644 under the usual 022), like every other tool:
    safetensors and mkstemp create theirs 0600."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def write_tensors(path: Path, tensors: dict[str, torch.Tensor], meta: dict[str, Any] | None = None) -> None:
    """Tensors (moved to CPU) and JSON metadata into one safetensors file: no pickle anywhere."""
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    save_file(tensors, str(path), metadata={_META_KEY: json.dumps(meta or {})})
    umask_permissions(path)
    with open(path, "rb+") as f:
        os.fsync(f.fileno())


def read_tensors(root: Path, name: str, manifest: dict[str, Any]) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The tensors and JSON metadata of `root/name`, checked against the manifest first (CheckpointError)."""
    path = root / name
    verify(path, manifest)
    try:
        tensors = load_file(str(path))
        with safetensors.safe_open(str(path), framework="pt") as f:
            meta = json.loads((f.metadata() or {}).get(_META_KEY, "{}"))
    except Exception as e:  # safetensors raises several types on malformed files
        raise CheckpointError(f"{path}: unreadable safetensors file ({e})") from None
    check_recorded_shapes(root, name, manifest, tensors)
    return tensors, meta


def check_recorded_shapes(root: Path, name: str, manifest: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
    """CheckpointError naming manifest.json and `tensors.<name>` unless the shapes the manifest records for file
    `name` are those of its tensors (a manifest without `tensors`, as NPMP checkpoints write it, records none)."""
    if "tensors" not in manifest:
        return
    recorded, where = manifest["tensors"], f"{root / MANIFEST_FILE}: tensors"
    if not isinstance(recorded, dict):
        raise CheckpointError(f"{where}: must map file names to {{tensor: shape}}, got {type(recorded).__name__}")
    actual = {k: list(v.shape) for k, v in tensors.items()}
    if name not in recorded:
        raise CheckpointError(f"{where}.{name}: missing (the shapes of every safetensors file are recorded)")
    if recorded[name] != actual:
        entry = recorded[name] if isinstance(recorded[name], dict) else {}
        diff = sorted(set(entry) ^ set(actual)) or sorted(k for k in actual if entry.get(k) != actual[k])
        key = diff[0] if diff else "?"
        raise CheckpointError(f"{where}.{name}: disagrees with {name} (at {key!r}: recorded "
                              f"{entry.get(key, 'nothing')}, the file holds {actual.get(key, 'nothing')})")


def check_recorded_sizes(path: Path, manifest: dict[str, Any], sizes: dict[str, int]) -> None:
    """CheckpointError naming manifest.json and `model.<key>` unless the model sizes the manifest records are those
    of the model built from the checkpoint (`sizes`); a manifest without `model` records none."""
    if "model" not in manifest:
        return
    recorded, where = manifest["model"], f"{path / MANIFEST_FILE}: model"
    if not isinstance(recorded, dict):
        raise CheckpointError(f"{where}: must map obs_dim, action_dim and z_dim to sizes, "
                              f"got {type(recorded).__name__}")
    for key in sorted(set(recorded) | set(sizes)):
        if recorded.get(key) != sizes.get(key) or isinstance(recorded.get(key), bool):
            raise CheckpointError(f"{where}.{key}: {recorded.get(key, 'missing')!r} disagrees with the model its "
                                  f"files hold ({sizes.get(key, 'no such size')})")


def read_trainer_meta(path: str | Path) -> dict[str, Any]:
    """The JSON counters of a checkpoint's trainer state, read from the safetensors header only (no tensors)."""
    file = Path(path) / TRAINER_FILE
    try:
        with safetensors.safe_open(str(file), framework="pt") as f:
            return json.loads((f.metadata() or {}).get(_META_KEY, "{}"))
    except FileNotFoundError:
        raise CheckpointError(f"{file}: missing (an inference-only checkpoint cannot be resumed)") from None
    except Exception as e:  # safetensors raises several types on malformed files
        raise CheckpointError(f"{file}: unreadable safetensors file ({e})") from None


def verify(path: Path, manifest: dict[str, Any]) -> None:
    """CheckpointError unless `path` exists with the size and hash its manifest entry records."""
    entry = manifest.get("files", {}).get(path.name)
    if not path.is_file():
        raise CheckpointError(f"{path}: file missing from checkpoint")
    if entry is None:
        raise CheckpointError(f"{path}: not listed in {MANIFEST_FILE}")
    if path.stat().st_size != entry["bytes"] or sha256(path) != entry["sha256"]:
        raise CheckpointError(f"{path}: checksum mismatch with {MANIFEST_FILE} (file corrupted or truncated)")


def seal(tmp: Path, path: Path, algorithm: str, model: dict[str, int], extra: dict[str, Any] | None = None) -> None:
    """Hash every file written to the staging folder `tmp`, add the manifest (format, method, versions, model
    sizes, `extra`), and swap it into place at `path`: every checkpoint kind is finished the same way."""
    files = {p.name: {"bytes": p.stat().st_size, "sha256": sha256(p)} for p in sorted(tmp.iterdir())}
    manifest = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "algorithm": algorithm,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "versions": {"fbcpr": fbcpr.__version__, "torch": torch.__version__, "numpy": np.__version__,
                     "safetensors": getattr(safetensors, "__version__", "?")},
        "model": model,
        "files": files,
        **(extra or {}),
    }
    (tmp / MANIFEST_FILE).write_text(json.dumps(manifest, indent=1))
    fsync_dir(tmp)
    swap_into_place(tmp, path)


def _model_sizes(model: torch.nn.Module) -> dict[str, int]:
    """The manifest's sizes of a method's model: each keeps the `ModelConfig` it was built from (as `cfg`, its sizes
    set, or it would not have built) and has a `z_dim`."""
    cfg, z_dim = model.cfg, model.z_dim
    assert isinstance(cfg, ModelConfig) and cfg.obs_dim is not None and cfg.action_dim is not None
    assert isinstance(z_dim, int)
    return {"obs_dim": cfg.obs_dim, "action_dim": cfg.action_dim, "z_dim": z_dim}


def save_checkpoint(
    path: str | Path,
    model: torch.nn.Module,
    config: Config | ModelConfig,
    trainer_state: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None,
    reward_buffer: Mapping[str, np.ndarray | torch.Tensor] | None = None,
    replay_buffer: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None,
    reward_dtype: torch.dtype = torch.float32,
    reward_obs: bool = True,
    reward_prompts: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None,
) -> Path:
    """Write a checkpoint directory at `path` atomically (replacing any checkpoint already there).

    `reward_dtype=torch.float16` halves the reward-inference buffer and `reward_obs=False` stores its states
    without their observations (rebuilt on load), for checkpoints that ship. `reward_prompts` is the (tensors,
    metadata) pair of `fbcpr.inference.reward_prompts.RewardPrompts.to_tensors`."""
    path = Path(path)
    tmp = staging_dir(path)
    try:
        shapes: dict[str, dict[str, list[int]]] = {}

        def put(name: str, tensors: dict[str, torch.Tensor], meta: dict[str, Any] | None = None) -> None:
            write_tensors(tmp / name, tensors, meta)
            shapes[name] = {k: list(v.shape) for k, v in tensors.items()}

        put(MODEL_FILE, dict(model.state_dict()))
        if trainer_state is not None:
            put(TRAINER_FILE, *trainer_state)
        if reward_buffer is not None:
            keys = REWARD_KEYS if reward_obs else STATE_KEYS
            missing = [k for k in keys if k not in reward_buffer]
            if missing:
                raise CheckpointError(f"reward_buffer: missing arrays {missing}")
            arrays = {k: torch.as_tensor(np.asarray(reward_buffer[k])).to(reward_dtype) for k in keys}
            finite = torch.stack([torch.isfinite(v.reshape(len(v), -1)).all(1) for v in arrays.values()]).all(0)
            put(REWARD_FILE, {k: v[finite] for k, v in arrays.items()})  # one inf row would break every reward prompt
        if reward_prompts is not None:
            put(PROMPTS_FILE, *reward_prompts)
        if replay_buffer is not None:
            put(REPLAY_FILE, *replay_buffer)
        cfg_data = (config_to_dict(data_relative_config(config)) if isinstance(config, Config)
                    else {"model": config_to_dict(config)})
        (tmp / CONFIG_FILE).write_text(yaml.safe_dump(cfg_data, sort_keys=False))
        seal(tmp, path, config.algorithm if isinstance(config, Config) else DEFAULT_ALGORITHM,
             _model_sizes(model), {"tensors": shapes})
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def discard_checkpoint(path: Path) -> None:
    """Delete a checkpoint by renaming it to a hidden temporary name first, so a kill during the deletion never
    leaves a half-deleted folder under a real checkpoint name (the leftover goes at the next start)."""
    doomed = path.parent / f".{path.name}.deleting-{uuid.uuid4().hex[:8]}"
    os.rename(path, doomed)
    shutil.rmtree(doomed, ignore_errors=True)


def remove_stale_temporaries(root: Path) -> list[Path]:
    """Remove what killed saves and deletions left in a checkpoints folder (`.NAME.tmp-*`, `.NAME.deleting-*`,
    `.latest.tmp`, `.best.tmp`); `.NAME.previous` backups stay, as load_checkpoint falls back to them. Returns what
    went."""
    pointer_tmps = {f".{p}.tmp" for p in POINTERS}
    stale = [p for p in root.glob(".*") if ".tmp-" in p.name or ".deleting-" in p.name or p.name in pointer_tmps]
    for p in stale:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    return stale


def fsync_dir(path: Path) -> None:
    """Flush a folder's entries to disk, so a rename survives a power cut."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _backup_name(path: Path) -> Path:
    return path.parent / f".{path.name}.previous"


def check_replaceable(path: Path, marker: str = MANIFEST_FILE) -> None:
    """CheckpointError unless a checkpoint may be written at `path`: nothing is there, an empty folder, or a
    checkpoint (a folder with its manifest, or the `marker` file of another kind of export). A file, or a folder of
    anything else, is never replaced by one."""
    if not os.path.lexists(path):
        return
    if not path.is_dir():
        raise CheckpointError(f"{path}: an existing file, not a checkpoint folder; a checkpoint would replace it "
                              "(choose another path)")
    try:
        holds = next(os.scandir(path), None) is not None
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read the folder to be replaced ({e.strerror})") from None
    if holds and not (path / marker).is_file():
        raise CheckpointError(f"{path}: a folder that holds files but no checkpoint (no {marker}); a checkpoint "
                              "would replace all of it (choose another path)")


def staging_dir(path: Path, marker: str = MANIFEST_FILE) -> Path:
    """A fresh hidden folder beside `path` to write a checkpoint into before `swap_into_place` (refused early, by
    `check_replaceable`, where no checkpoint may go); `remove_stale_temporaries` finds those a kill left behind."""
    check_replaceable(path, marker)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    return tmp


def swap_into_place(tmp: Path, path: Path, marker: str = MANIFEST_FILE) -> None:
    """tmp -> path; an existing checkpoint is kept as a backup until the new one is in place (`check_replaceable`:
    only a checkpoint, one with `marker`, or an empty folder is replaced)."""
    check_replaceable(path, marker)
    backup = _backup_name(path)
    if path.exists():
        if backup.exists():
            shutil.rmtree(backup)
        os.rename(path, backup)
    os.rename(tmp, path)
    fsync_dir(path.parent)
    shutil.rmtree(backup, ignore_errors=True)


def list_checkpoints(root: Path) -> list[Path]:
    """A run's checkpoint folders (`root/step_*`), oldest first: the zero-padded step count sorts by name."""
    return sorted(p for p in root.glob("step_*") if p.is_dir())


def prunable_checkpoints(root: Path, keep_last: int, keep_every: int) -> list[Path]:
    """Checkpoints that retention removes: all but the last `keep_last`, sparing those at multiples of
    `keep_every` env steps (0: none spared)."""
    steps = list_checkpoints(root)[:-keep_last]
    return [p for p in steps if not (keep_every and int(p.name.split("_")[1]) % keep_every == 0)]


def pointed_checkpoint(root: Path, pointer: str = "latest") -> Path:
    """The checkpoint that `root/<pointer>` names (`latest`, or `best` with `train.keep_best`); CheckpointError naming
    the pointer when it is missing, empty, or points anywhere but a sibling checkpoint folder (a loop such as `.`
    or a pointer's own name included)."""
    check_folder_link(root)
    file = root / pointer
    if file.is_dir():
        link = f" (a symbolic link to {os.readlink(file)})" if file.is_symlink() else ""
        raise CheckpointError(f"{file}: a folder{link}; `{pointer}` must be a text file holding the name of a "
                              "checkpoint folder beside it (e.g. step_0000100000), not the folder or a link to it")
    try:
        name = file.read_text().strip()
    except FileNotFoundError:
        if file.is_symlink():
            raise CheckpointError(f"{file}: a symbolic link to {os.readlink(file)}, which does not exist") from None
        raise CheckpointError(f"{file}: missing (no checkpoint to resume)") from None
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise CheckpointError(f"{file}: a symbolic link loop (it leads back to itself); it must be a file naming "
                                  "a checkpoint folder beside it") from None
        raise CheckpointError(f"{file}: unreadable pointer ({e})") from None
    except UnicodeDecodeError as e:
        raise CheckpointError(f"{file}: unreadable pointer ({e})") from None
    if not name or name in (".", "..", *POINTERS) or "/" in name or os.sep in name:
        raise CheckpointError(f"{file}: must name a checkpoint folder beside it (e.g. step_0000100000), got {name!r}")
    return root / name


def check_folder_link(path: Path) -> None:
    """CheckpointError when `path` is a symbolic link that leads nowhere (a loop, or a missing target): reading
    through it would only say that the files inside are missing."""
    if not path.is_symlink() or path.exists():
        return
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise CheckpointError(f"{path}: a symbolic link loop (it leads back to itself); it must be a checkpoint "
                                  "folder, or a link to one") from None
    raise CheckpointError(f"{path}: a symbolic link to {os.readlink(path)}, which does not exist")


def latest_checkpoint(root: Path) -> Path:
    """The checkpoint `root/latest` names: what a resume continues from."""
    return pointed_checkpoint(root, "latest")


def write_pointer(root: Path, pointer: str, name: str) -> None:
    """Point `root/<pointer>` at the checkpoint folder `name`, atomically: a crash leaves the old pointer or the new."""
    tmp = root / f".{pointer}.tmp"
    tmp.write_text(name)
    os.replace(tmp, root / pointer)


def read_manifest(file: Path) -> dict[str, Any]:
    """manifest.json, checked against its schema (format, version, one {bytes, sha256} entry per file), so a
    damaged manifest is a CheckpointError naming the key, never an AttributeError deep inside the loader."""
    try:
        manifest = json.loads(file.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise CheckpointError(f"{file}: missing") from None
    except OSError as e:
        raise CheckpointError(f"{file}: cannot read ({e.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise CheckpointError(f"{file}: invalid JSON ({e.__class__.__name__}: {str(e).splitlines()[0][:80]})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise CheckpointError(f"{file}: not an {FORMAT} manifest")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{file}: format_version {manifest.get('format_version')!r} "
                              f"is not supported (expected {FORMAT_VERSION})")
    if not isinstance(manifest.get("algorithm", DEFAULT_ALGORITHM), str):
        raise CheckpointError(f"{file}: 'algorithm' must be a string")
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise CheckpointError(f"{file}: 'files' must map file names to {{bytes, sha256}}, got {type(files).__name__}")
    for name, entry in files.items():
        ok = (isinstance(entry, dict) and isinstance(entry.get("bytes"), int) and not isinstance(entry["bytes"], bool)
              and entry["bytes"] >= 0 and isinstance(entry.get("sha256"), str) and len(entry["sha256"]) == 64)
        if not ok:
            raise CheckpointError(f"{file}: files.{name}: must be {{\"bytes\": int >= 0, \"sha256\": 64 hex digits}}")
    return manifest


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> Checkpoint:
    """Load and verify a checkpoint directory; never unpickles. Raises CheckpointError naming the problem."""
    path = Path(path)
    if not path.exists() and _backup_name(path).exists():
        path = _backup_name(path)  # a save was interrupted between its two renames: the old one is intact
    if not path.is_dir():
        raise CheckpointError(f"{path}: not a checkpoint directory")
    manifest = read_manifest(path / MANIFEST_FILE)
    recorded = manifest.get("algorithm", DEFAULT_ALGORITHM)
    if recorded not in METHODS:
        raise CheckpointError(f"{path}: holds a {recorded!r} model, not an agent of `fbcpr train` (an NPMP checkpoint "
                              "tracks clips: `fbcpr track`, `fbcpr eval --suite tracking`)")
    verify(path / CONFIG_FILE, manifest)
    try:
        data = yaml.safe_load((path / CONFIG_FILE).read_text())
        if isinstance(data, dict) and isinstance(data.get("env"), dict):
            data["env"].setdefault("action_mapping", LEGACY_ACTION_MAPPING)  # written before the option existed
        config: Config | ModelConfig = (expand_data_paths(config_from_dict(data)) if set(data) != {"model"}
                                        else model_config_from_dict(data["model"]))
    except (yaml.YAMLError, ConfigError, TypeError, AttributeError) as e:
        raise CheckpointError(f"{path / CONFIG_FILE}: invalid config ({e})") from None
    mcfg = config.model if isinstance(config, Config) else config
    algorithm = config.algorithm if isinstance(config, Config) else DEFAULT_ALGORITHM
    if manifest.get("algorithm", DEFAULT_ALGORITHM) != algorithm:
        raise CheckpointError(f"{path / MANIFEST_FILE}: algorithm {manifest.get('algorithm')!r} disagrees with "
                              f"{algorithm!r} of {CONFIG_FILE}")
    try:
        model = get_method(algorithm).model(mcfg)
    except ValueError as e:
        raise CheckpointError(f"{path / CONFIG_FILE}: {e}") from None
    tensors, _ = read_tensors(path, MODEL_FILE, manifest)
    load_state_strict(model, tensors, str(path / MODEL_FILE))
    check_recorded_sizes(path, manifest, _model_sizes(model))
    model.to(device)
    model.eval()
    return Checkpoint(path=path, model=model, config=config, manifest=manifest)


def load_state_strict(module: torch.nn.Module, tensors: dict[str, torch.Tensor], where: str) -> None:
    """load_state_dict with errors that name the first missing, unexpected or mis-shaped tensor."""
    expected = module.state_dict()
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    if missing:
        raise CheckpointError(f"{where}: missing tensor {missing[0]!r} ({len(missing)} missing)")
    if unexpected:
        raise CheckpointError(f"{where}: unexpected tensor {unexpected[0]!r} (config mismatch?)")
    for k, v in expected.items():
        if tuple(tensors[k].shape) != tuple(v.shape) or tensors[k].dtype != v.dtype:
            raise CheckpointError(f"{where}: tensor {k!r} has shape {tuple(tensors[k].shape)} {tensors[k].dtype}, "
                                  f"config expects {tuple(v.shape)} {v.dtype}")
        if v.is_floating_point() and not torch.isfinite(tensors[k]).all():
            raise CheckpointError(f"{where}: tensor {k!r} contains NaN or inf")
    module.load_state_dict(tensors)


def inconsistent_rows(buf: dict[str, np.ndarray], env_name: str, rows: int = 64) -> float:
    """Share of the first `rows` rows whose next_obs is not the observation of their own (qpos, qvel), to float16
    precision (0.0 for an empty sample). Rows mixed across transitions score about 1.0."""
    n = min(rows, len(buf["qpos"]))
    if n == 0:
        return 0.0
    rebuilt = env_kind(env_name).observer()(buf["qpos"][:n], buf["qvel"][:n])
    stored = np.asarray(buf["next_obs"][:n], dtype=np.float32)
    ok = np.isclose(rebuilt, stored, rtol=0.02, atol=0.02).all(axis=1)
    return float(1.0 - ok.mean())
