"""`BFM`: a trained FB-CPR model ready to prompt and act, loaded from a checkpoint directory or the Hugging Face Hub.

    bfm = BFM.load("runs/demo")                         # or BFM.load("org/fbcpr-humanoid")
    z = bfm.prompt.reward("move-ego-0-2")               # also .goal("t_pose"), .track(clip), .imitate(clip)
    action = bfm.act(obs, z)                            # numpy or torch, (358,) or (N, 358)

BFM also is an evaluation Agent (`act`, `z_dim`, `reward_z`, `goal_z`, `track_z`).
"""
from __future__ import annotations

import difflib
import numbers
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Literal, TypeVar, overload

import numpy as np
import torch
import yaml

from fbcpr.core.checkpoint import (
    CONFIG_FILE,
    MANIFEST_FILE,
    MODEL_FILE,
    POINTERS,
    PROMPTS_FILE,
    REWARD_FILE,
    REWARD_KEYS,
    Checkpoint,
    CheckpointError,
    check_folder_link,
    inconsistent_rows,
    latest_checkpoint,
    load_checkpoint,
    pointed_checkpoint,
    save_checkpoint,
)
from fbcpr.core.config import portable_config
from fbcpr.core.errors import InputError
from fbcpr.core.schema import Config, ModelConfig, batch_config, config_to_dict, env_of
from fbcpr.inference.prompt import Prompt
from fbcpr.inference.reward_prompts import RewardPrompts, load_reward_prompts, weights_digest
from fbcpr.methods.fb_cpr.config import AgentConfig
from fbcpr.methods.fb_cpr.model import FBCPRModel

ArrayLike = TypeVar("ArrayLike", torch.Tensor, np.ndarray)

#: Files an inference checkpoint needs (the trainer state and the full replay buffer are never fetched).
HUB_FILES = [MODEL_FILE, CONFIG_FILE, MANIFEST_FILE, REWARD_FILE, PROMPTS_FILE, "README.md"]
_REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[\w.-]+$")
_CHUNK = 16_384
#: The shipped inference checkpoint; "pretrained" names it wherever a checkpoint path is accepted.
PRETRAINED_NAME = "pretrained"
PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "pretrained"


class BFM:
    """Inference wrapper around an `FBCPRModel`: act, embed states with B, prompt, save and share."""

    def __init__(
        self,
        model: FBCPRModel,
        config: Config | ModelConfig,
        reward_buffer: dict[str, np.ndarray] | None = None,
        metrics: dict[str, float] | None = None,
        source: str | None = None,
        checkpoint: Checkpoint | None = None,
        reward_prompts: RewardPrompts | None = None,
    ) -> None:
        self.model = model.eval()
        self.config = config
        self.metrics: dict[str, float] = dict(metrics or {})
        self.source = source
        self._reward_buffer = reward_buffer
        self._checkpoint = checkpoint  # lazy access to reward_buffer.safetensors
        #: z's of named tasks inferred at export from more states than the checkpoint keeps
        #: (`fbcpr.inference.reward_prompts`)
        self.reward_prompts = reward_prompts
        stored = checkpoint.reward_prompts() if checkpoint is not None and reward_prompts is None else None
        if checkpoint is not None and stored is not None:
            self.reward_prompts = load_reward_prompts(*stored, model, checkpoint.path)
        self._prompt: Prompt | None = None
        self._samples: tuple[tuple[int, int], dict[str, np.ndarray], torch.Tensor] | None = None
        self._buffer_checked = False

    # ------------------------------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        path_or_repo_id: str | Path = PRETRAINED_NAME,
        device: str | torch.device = "cpu",
        revision: str | None = None,
        cache_dir: str | Path | None = None,
    ) -> BFM:
        """Load from a checkpoint directory (a training run directory means its latest checkpoint), `pretrained`
        (the default: the shipped model, as `BFM.pretrained()`), or a Hugging Face repo id (downloaded once into
        the HF cache; HF_HUB_OFFLINE=1 uses the cache only)."""
        path = resolve_checkpoint(path_or_repo_id, revision=revision, cache_dir=cache_dir)
        ckpt = load_checkpoint(path, device=device)
        if ckpt.algorithm != "fb_cpr":
            raise CheckpointError(f"{path}: holds a {ckpt.algorithm} agent, not a prompt-able FB-CPR model "
                                  "(evaluate it with `fbcpr eval`, which runs any agent)")
        assert isinstance(ckpt.model, FBCPRModel)  # the model of an fb_cpr checkpoint
        return cls(ckpt.model, ckpt.config, source=str(path_or_repo_id), checkpoint=ckpt)

    @classmethod
    def pretrained(cls, device: str | torch.device = "cpu") -> BFM:
        """The model that ships inside the package (`fbcpr/pretrained/`, its model card is the README there)."""
        return cls.load(pretrained_dir(), device=device)

    # ---------------------------------------------------------------------------------- properties
    @property
    def device(self) -> torch.device:
        return self.model.device

    @property
    def obs_dim(self) -> int:
        obs_dim = self.model.cfg.obs_dim
        assert obs_dim is not None  # a built model has its sizes
        return int(obs_dim)

    @property
    def action_dim(self) -> int:
        action_dim = self.model.cfg.action_dim
        assert action_dim is not None
        return int(action_dim)

    @property
    def z_dim(self) -> int:
        return int(self.model.cfg.z_dim)

    @property
    def env_name(self) -> str:
        """The env the model was trained on (`fbcpr.core.config.env_of`)."""
        return env_of(self.config).name

    @property
    def action_mapping(self) -> str:
        """How the env must map this model's actions to PD targets (`humanoid_env.actions`), as it was trained."""
        return env_of(self.config).action_mapping

    @property
    def sequence_length(self) -> int:
        """L of ER_FB, the training sequence length (the paper's 8 when the checkpoint has no agent config)."""
        agent = batch_config(self.config.agent) if isinstance(self.config, Config) else AgentConfig()
        return int(agent.seq_length)

    @property
    def reward_buffer(self) -> dict[str, np.ndarray] | None:
        """The reward-inference buffer (next_obs, qpos, qvel), read from the checkpoint on first use."""
        if self._reward_buffer is None and self._checkpoint is not None:
            self._reward_buffer = self._checkpoint.reward_buffer()
            self._checkpoint = None
        if self._reward_buffer is not None and not self._buffer_checked:
            check_reward_buffer(self._reward_buffer, self.obs_dim, self.env_name)
            self._buffer_checked = True
        return self._reward_buffer

    def reward_samples(self, n: int, seed: int = 0) -> tuple[dict[str, np.ndarray], torch.Tensor]:
        """Up to n reward-buffer samples (drawn without replacement, seeded) and their B, cached for the next prompt.

        Computing B over 100k states is most of a reward prompt's cost; relabeling with a new reward is cheap.
        """
        buf = self.reward_buffer
        if buf is None:
            raise CheckpointError("this model has no reward-inference buffer (reward_buffer.safetensors)")
        if self._samples is None or self._samples[0] != (n, seed):
            size = buf["next_obs"].shape[0]
            if size <= n:
                samples = buf
            else:
                idx = np.sort(np.random.default_rng(seed).choice(size, n, replace=False))
                samples = {k: v[idx] for k, v in buf.items()}
            self._samples = ((n, seed), samples, self.backward(samples["next_obs"], as_tensor=True))
        return self._samples[1], self._samples[2]

    @property
    def prompt(self) -> Prompt:
        """The prompt layer for this model (its reward-buffer embeddings are cached across reward prompts)."""
        if self._prompt is None:
            self._prompt = Prompt(self)
        return self._prompt

    # --------------------------------------------------------------------------------- inference
    def act(self, obs: ArrayLike, z: ArrayLike, mean: bool = True,
            generator: torch.Generator | None = None) -> ArrayLike:
        """Actions in [-1, 1] for obs (obs_dim,) or (N, obs_dim) and z (z_dim,) or (N, z_dim).

        Returns the kind of `obs` (numpy or torch) with its batch convention; a single z is shared by a batch.
        z is projected onto the model's sqrt(z_dim) sphere first, where every prompt's z lies and the policy was
        trained, so a z of any nonzero norm is used by its direction. Actions are always finite: an obs so far
        outside the training range that the policy would output NaN raises InputError (a ValueError) instead.
        """
        as_torch = isinstance(obs, torch.Tensor)
        o, zt = self._tensor(obs, "obs"), self._tensor(z, "z")
        obs_shape, z_shape = tuple(o.shape), tuple(zt.shape)
        single = o.dim() == 1
        o = o.unsqueeze(0) if single else o
        if o.dim() != 2 or o.shape[1] != self.obs_dim:
            raise InputError(f"obs: expected shape ({self.obs_dim},) or (N, {self.obs_dim}), got {obs_shape}")
        zt = zt.unsqueeze(0).expand(o.shape[0], -1) if zt.dim() == 1 else zt
        if zt.dim() != 2 or zt.shape[1] != self.z_dim or zt.shape[0] != o.shape[0]:
            raise InputError(f"z: expected shape ({self.z_dim},) or ({o.shape[0]}, {self.z_dim}), got {z_shape}")
        if not (_all_finite(o) and _all_finite(zt)):
            raise InputError("obs and z must be finite (found NaN or inf)")
        norms = torch.linalg.vector_norm(zt.double(), dim=-1)
        if not bool((norms > 0).all()):
            raise InputError("z: must be nonzero (it is projected onto the sphere of radius sqrt(z_dim))")
        with torch.inference_mode():
            zt = self.model.project_z((zt.double() / norms[:, None]).to(zt.dtype))  # unit first: 1e30 would overflow
            a = self.model.act(o, zt, mean=mean, generator=generator)
        if not _all_finite(a):
            raise InputError("obs: gives non-finite actions (values far outside the observation range the model "
                             "was trained on)")
        a = a[0] if single else a
        return a if as_torch else a.cpu().numpy()

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: Literal[True]) -> torch.Tensor: ...

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: Literal[False] = False) -> np.ndarray: ...

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: bool) -> np.ndarray | torch.Tensor: ...

    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: bool = False) -> np.ndarray | torch.Tensor:
        """B(s) for observations (obs_dim,) or (N, obs_dim) -> (N, z_dim), in chunks, under inference mode."""
        o = self._tensor(obs, "obs")
        o = o.unsqueeze(0) if o.dim() == 1 else o
        if o.dim() != 2 or o.shape[1] != self.obs_dim:
            raise InputError(f"obs: expected shape ({self.obs_dim},) or (N, {self.obs_dim}), got {tuple(o.shape)}")
        if not _all_finite(o):
            raise InputError("obs must be finite (found NaN or inf)")
        b = o.new_empty(o.shape[0], self.z_dim)
        with torch.inference_mode():
            for start in range(0, o.shape[0], _CHUNK):
                b[start:start + _CHUNK] = self.model.backward(o[start:start + _CHUNK])
        return b if as_tensor else b.cpu().numpy()

    def project_z(self, z: np.ndarray | torch.Tensor) -> np.ndarray:
        """float32 numpy z on the sqrt(d) sphere (the model's projection)."""
        with torch.inference_mode():
            out = self.model.project_z(torch.as_tensor(z, dtype=torch.float32))
        return out.cpu().numpy().astype(np.float32)

    def _tensor(self, x: Any, name: str) -> torch.Tensor:
        """`x` as a float32 tensor on the model's device; InputError naming `name` unless it holds real numbers (a
        complex value would lose its imaginary part, and None would become NaN)."""
        if isinstance(x, torch.Tensor):
            if x.is_complex():
                raise InputError(f"{name}: must be real numbers, got complex values ({x.dtype})")
            return x.to(device=self.device, dtype=torch.float32)
        try:
            raw = np.asarray(x)
        except (TypeError, ValueError) as err:
            raise InputError(f"{name}: expected a numpy array or torch tensor of numbers ({err})") from None
        if raw.dtype.kind == "c":
            raise InputError(f"{name}: must be real numbers, got complex values ({raw.dtype})")
        if raw.dtype.kind == "O":
            bad = next((i for i, v in enumerate(raw.flat) if not isinstance(v, (numbers.Real, np.bool_))), -1)
            if bad >= 0:  # None included, which float32 would turn into NaN
                value = raw.flat[bad]
                raise InputError(f"{name}: must be numbers, found {type(value).__name__} values ({value!r})")
        elif raw.dtype.kind not in "biuf":
            raise InputError(f"{name}: must be numbers, got an array of {raw.dtype}")
        try:
            arr = np.asarray(raw, dtype=np.float32)
        except (TypeError, ValueError) as err:
            raise InputError(f"{name}: expected a numpy array or torch tensor of numbers ({err})") from None
        if not arr.flags.writeable:  # read-only views (np.broadcast_to, memmaps): torch wants memory it may write
            arr = arr.copy()
        return torch.as_tensor(arr, device=self.device)

    # ------------------------------------------------------------------------- agent protocol
    def reward_z(self, task: Any, **kwargs: Any) -> np.ndarray:
        """z for a reward task name (or callable); see `Prompt.reward`."""
        return self.prompt.reward(task, **kwargs)

    def goal_z(self, goal: Any, **kwargs: Any) -> np.ndarray:
        """z for a goal observation, qpos pose or goal name; see `Prompt.goal`."""
        return self.prompt.goal(goal, **kwargs)

    def track_z(self, obs_seq: Any) -> np.ndarray:
        """(T-1, z_dim) per-step zs to track a motion; see `Prompt.track`."""
        return self.prompt.track(obs_seq)

    def imitate_z(self, motion: Any) -> np.ndarray:
        """One z for a whole motion; see `Prompt.imitate`."""
        return self.prompt.imitate(motion)

    # ---------------------------------------------------------------------------------- saving
    def save(self, path: str | Path, reward_samples: int | None = None, half: bool = False,
             states_only: bool = False) -> Path:
        """Write an inference checkpoint (model, config, reward-inference buffer) atomically at `path`; paths of the
        config under the working directory are written relative to it (`portable_config`).

        `reward_samples` keeps a seeded subsample of the reward buffer, `half` stores it as float16 and
        `states_only` drops its observations, which loading rebuilds from the states: the compact form a
        checkpoint that ships with a package or an app needs (a smaller buffer costs some prompt quality).
        Stored reward prompts are written too, unless the weights changed since."""
        buf = self.reward_buffer
        if buf is not None and reward_samples is not None:
            if reward_samples < 1:
                raise InputError(f"reward_samples must be >= 1, got {reward_samples}")
            buf = self.reward_samples(reward_samples, seed=0)[0]
        cfg = portable_config(self.config) if isinstance(self.config, Config) else self.config
        prompts = self.reward_prompts  # dropped if the weights changed since they were inferred
        keep = prompts if prompts is not None and prompts.digest == weights_digest(self.model) else None
        return save_checkpoint(path, self.model, cfg, reward_buffer=buf,
                               reward_dtype=torch.float16 if half else torch.float32, reward_obs=not states_only,
                               reward_prompts=keep.to_tensors() if keep is not None else None)

    def save_for_hub(self, path: str | Path, metrics: dict[str, float] | None = None,
                     repo_id: str | None = None) -> Path:
        """The folder `push_to_hub` uploads: an inference checkpoint plus a README.md model card."""
        path = self.save(path)
        card = model_card(self, {**self.metrics, **(metrics or {})}, repo_id or "<owner>/<name>")
        (path / "README.md").write_text(card)
        return path

    def push_to_hub(
        self,
        repo_id: str,
        metrics: dict[str, float] | None = None,
        private: bool | None = None,
        token: str | None = None,
        commit_message: str = "Upload FB-CPR model",
    ) -> Any:
        """Create the repo if needed and upload the `save_for_hub` folder; returns the commit info."""
        import huggingface_hub

        if not _REPO_ID.match(repo_id):
            raise InputError(f"{repo_id!r} is not a Hugging Face repo id (expected 'owner/name')")
        with tempfile.TemporaryDirectory(prefix="fbcpr-hub-") as tmp:
            folder = self.save_for_hub(Path(tmp) / "model", metrics=metrics, repo_id=repo_id)
            huggingface_hub.create_repo(repo_id, token=token, private=private, exist_ok=True)
            return huggingface_hub.upload_folder(
                repo_id=repo_id, folder_path=folder, token=token, commit_message=commit_message
            )


def check_compatible(a: BFM, b: BFM, action: str, same_networks: bool) -> None:
    """Raise CheckpointError unless two models can be combined by `action` (e.g. "interpolate X and Y"): the same
    env, action mapping and z size, and with `same_networks` the same model config, so their weights match."""
    pairs = [("env", a.env_name, b.env_name), ("action mapping", a.action_mapping, b.action_mapping),
             ("model config", a.model.cfg, b.model.cfg) if same_networks else ("z_dim", a.z_dim, b.z_dim)]
    for what, x, y in pairs:
        if x != y:
            raise CheckpointError(f"cannot {action}: their {what} differs ({x} against {y})")


def check_reward_buffer(buf: dict[str, np.ndarray], obs_dim: int, env_name: str) -> None:
    """next_obs (N, obs_dim) with N >= 1, qpos and qvel (N, ·), all finite, each row one state's; CheckpointError
    naming what is wrong."""
    missing = [k for k in REWARD_KEYS if k not in buf]
    if missing:
        raise CheckpointError(f"reward-inference buffer: missing arrays {missing}")
    n = len(buf["next_obs"])
    for key in REWARD_KEYS:
        shape = np.shape(buf[key])
        width = obs_dim if key == "next_obs" else shape[-1] if len(shape) == 2 else "·"
        if len(shape) != 2 or shape[0] != n or n == 0 or shape[1] != width:
            raise CheckpointError(f"reward-inference buffer: {key} has shape {shape}, expected ({n or 'N>0'}, {width})")
        if not np.isfinite(np.sum(buf[key], dtype=np.float64)):
            raise CheckpointError(f"reward-inference buffer: {key} contains NaN or inf")
    if inconsistent_rows(buf, env_name) > 0.5:
        raise CheckpointError("reward-inference buffer: its next_obs rows are not the observations of its qpos/qvel "
                              "rows, so reward prompts would pair one state's reward with another's embedding (runs "
                              "resumed before this was checked mixed them). Refresh it: resume the run with "
                              "--more-steps N and train.warmup_steps above N (docs/usage.md)")


def _all_finite(x: torch.Tensor) -> bool:
    """NaN/inf check by one float64 reduction (a NaN or inf anywhere makes the sum non-finite; float32 values
    cannot overflow it), cheaper than a full boolean mask on a 100k-state buffer."""
    return bool(torch.isfinite(x.sum(dtype=torch.float64)))


def pretrained_dir() -> Path:
    """The shipped checkpoint's folder, or a CheckpointError when an installation lacks it."""
    if not (PRETRAINED_DIR / MANIFEST_FILE).is_file():
        raise CheckpointError(f"{PRETRAINED_DIR}: the pretrained model is missing from this installation")
    return PRETRAINED_DIR


def resolve_checkpoint(src: str | Path, revision: str | None = None, cache_dir: str | Path | None = None) -> Path:
    """A local checkpoint directory as is (a run directory: its latest checkpoint; a `checkpoints/best` or `latest`
    pointer: the folder it names), `pretrained` (the shipped model, unless a local folder has that name), or a Hub
    repo id downloaded into (or found in) the HF cache."""
    path = Path(src).expanduser()
    try:
        exists = path.exists()
    except OSError as e:  # e.g. a name longer than the file system allows
        raise CheckpointError(f"{str(src)[:60]}{'...' if len(str(src)) > 60 else ''}: not a usable checkpoint path "
                              f"({e.strerror})") from None
    if str(src) == PRETRAINED_NAME and not exists:
        return pretrained_dir()
    if not exists and path.is_symlink():  # a dangling link or a loop: say so rather than "no such directory"
        if path.name in POINTERS:
            return pointed_checkpoint(path.parent, path.name)
        raise CheckpointError(f"{path}: a symbolic link that leads nowhere (to a missing path, or in a loop)")
    if exists:
        if path.is_file() and path.name in POINTERS:  # RUN/checkpoints/latest or .../best: the folder it names
            return pointed_checkpoint(path.parent, path.name)
        if not path.is_dir():
            raise CheckpointError(f"{path}: not a checkpoint directory (expected a folder with {MODEL_FILE})")
        return _latest_in_run(path)
    text = str(src)
    if not _REPO_ID.match(text) or _looks_like_path(text):
        close = difflib.get_close_matches(text, [PRETRAINED_NAME], n=1, cutoff=0.75)
        hint = f"; did you mean {PRETRAINED_NAME!r} (the shipped model)?" if close else ""
        raise CheckpointError(f"{text}: no such checkpoint directory{hint}")
    folder = Path(_download(text, revision, cache_dir))
    missing = [f for f in (MODEL_FILE, CONFIG_FILE, MANIFEST_FILE) if not (folder / f).is_file()]
    if missing:
        raise CheckpointError(f"Hugging Face repo {text!r} has no {missing[0]}: it is not an fbcpr checkpoint "
                              f"(or its download is incomplete)")
    return folder


def _looks_like_path(text: str) -> bool:
    """A local path that does not exist rather than a Hub repo id ('owner/name'): it starts with '.', '/' or '~',
    its owner part has a dot or is a local folder (runs/x with runs/ here)."""
    owner = text.split("/")[0]
    return text.startswith((".", "/", "~")) or "." in owner or Path(owner).is_dir()


def _latest_in_run(path: Path) -> Path:
    """A training run directory (or its checkpoints/ folder) stands for its latest checkpoint."""
    if (path / MANIFEST_FILE).exists():
        return path
    check_folder_link(path / "checkpoints")
    for root in (path / "checkpoints", path):
        if os.path.lexists(root / "latest"):  # a symbolic link loop included: reading it says so
            return latest_checkpoint(root)
    return path


def _download(repo_id: str, revision: str | None, cache_dir: str | Path | None) -> str:
    """snapshot_download with errors that say what to do; honours HF_HUB_OFFLINE=1 (cache only)."""
    from huggingface_hub import snapshot_download
    from huggingface_hub.errors import (
        HfHubHTTPError,
        IncompleteSnapshotError,
        LocalEntryNotFoundError,
        RepositoryNotFoundError,
        RevisionNotFoundError,
    )

    try:
        return snapshot_download(repo_id, revision=revision, cache_dir=cache_dir, allow_patterns=HUB_FILES)
    except RepositoryNotFoundError:
        raise CheckpointError(f"{repo_id}: neither a local checkpoint directory nor a Hugging Face repo "
                              "(check the name; private repos need `hf auth login`)") from None
    except RevisionNotFoundError:
        raise CheckpointError(f"{repo_id}: revision {revision!r} not found on the Hugging Face Hub") from None
    except (LocalEntryNotFoundError, IncompleteSnapshotError):
        raise CheckpointError(f"{repo_id}: no such checkpoint directory, and as a Hugging Face repo id it is not in "
                              "the local cache (HF_HUB_OFFLINE=1 or no network): download it once while "
                              "online") from None
    except HfHubHTTPError as err:
        raise CheckpointError(f"{repo_id}: Hugging Face Hub error ({err})") from None


def model_card(bfm: BFM, metrics: dict[str, float], repo_id: str) -> str:
    """README.md for the Hub: metadata header, what the model is, how to use it, its config and metrics."""
    from huggingface_hub import ModelCardData

    data = ModelCardData(
        library_name="fbcpr",
        tags=["reinforcement-learning", "behavioral-foundation-model", "fb-cpr", "mujoco", "humanoid"],
        pipeline_tag="reinforcement-learning",
    )
    cfg = config_to_dict(bfm.config) if isinstance(bfm.config, Config) else {"model": config_to_dict(bfm.config)}
    motions = cfg.get("env", {}).get("motions", "unknown")
    if metrics:
        rows = "\n".join(f"| {k} | {v:.4g} |" if isinstance(v, (int, float)) else f"| {k} | {v} |"
                         for k, v in sorted(metrics.items()))
        table = f"| metric | value |\n|---|---|\n{rows}"
    else:
        table = "No evaluation metrics were recorded for this checkpoint (run `fbcpr eval` and push again)."
    has_buffer = bfm.reward_buffer is not None
    prompts = bfm.reward_prompts
    stored = (f"\n- stored reward prompts: {len(prompts.z)} named tasks, inferred from {prompts.states:,} states"
              if prompts is not None else "")
    if prompts is not None and prompts.refined:
        stored += f"; refined by rollouts: {', '.join(sorted(prompts.refined))}"
    return f"""---
{data.to_yaml()}
---

# FB-CPR behavioral foundation model (SMPL humanoid)

A forward-backward model with conditional policy regularization (FB-CPR) for the MuJoCo SMPL humanoid of the
`fbcpr` package: one latent-conditioned policy that is prompted zero-shot with a reward, a goal pose or a motion.

- observation: {bfm.obs_dim} values, action: {bfm.action_dim} PD targets in [-1, 1], latent z: {bfm.z_dim} dims
- trained on motions: `{motions}`
- reward-inference buffer included: {"yes" if has_buffer else "no (reward prompts unavailable)"}{stored}

Check the license of the motion data the model was trained on before using it.

## Usage

```python
from fbcpr import BFM
from humanoid_env.env import HumanoidEnv

bfm = BFM.load("{repo_id}")
z = bfm.prompt.reward("move-ego-0-2")    # or bfm.prompt.goal("t_pose"), bfm.prompt.track("clip.npz")
env = HumanoidEnv(action_mapping=bfm.action_mapping)
obs, info = env.reset(seed=0)
for _ in range(300):
    obs, reward, terminated, truncated, info = env.step(bfm.act(obs, z))
```

## Metrics

{table}

## Config

```yaml
{yaml.safe_dump(cfg, sort_keys=False).rstrip()}
```
"""
