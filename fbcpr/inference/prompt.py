"""Prompts: turn a reward, a goal pose or a motion into a latent z for a trained `BFM` (paper App. C.5.3).

Every z is returned as a float32 numpy vector (or one row per step for tracking), projected onto the
sqrt(d) sphere that the policy was trained on:

- reward: weighted regression z ∝ Σ exp(τ r(s')) r(s') B(s') over the checkpoint's reward-inference buffer
  (τ = 10, up to 100k samples), or the plain FB regression z ∝ Σ r(s') B(s'). A checkpoint may store the z's of
  the named tasks, regressed at export on more states than it keeps, some refined by rollouts
  (`fbcpr.inference.reward_prompts`): those answer by default;
- goal: z = B(g), with zero velocities when the goal is a pose (the paper's, `backward`); or the goal as a reward
  on the reward-inference buffer, r(s') = exp(-d_smpl(s', g) / 2), inferred as a reward is (`states`): states
  the model visited, where B(g) of a motionless pose is not; or the projected sum of both (`mix`);
- track: z_t ∝ Σ_{j=t+1}^{t+L} B(s_j), the ER_FB encoding of the next L states (L = training sequence length),
  the window shrinking at the end of the clip; `refine=N` searches nearby z's with the simulator
  (`fbcpr.inference.track_refine`);
- imitate: ER_FB of the whole clip (mean of B over its states);
- mix: a weighted sum of zs, projected again.
Rewards compose before inference through the reward registry's `a*b` / `a+b` names.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol, Union, cast, get_args, overload

import numpy as np
import torch

from fbcpr.core.errors import PromptError
from fbcpr.inference.reward_spec import RewardSpec, reward_fn
from fbcpr.inference.track_refine import Receding, TrackRefined
from fbcpr.nn.latents import TEMPERATURE, reward_weights, tracking_sums

if TYPE_CHECKING:
    from motions.clip import Clip

#: A goal given by name, as a qpos (76,) pose, or as an observation (358,).
GoalSpec = Union[str, np.ndarray, torch.Tensor, Sequence[float]]
#: A motion given as a Clip, a clip file path, a built-in clip name, or an (T, 358) observation sequence.
MotionSpec = Union["Clip", str, Path, np.ndarray, torch.Tensor]

N_REWARD_SAMPLES = 100_000
#: How a goal becomes a z (see the module docstring).
GoalMethod = Literal["backward", "states", "mix"]
GOAL_METHODS: tuple[str, ...] = get_args(GoalMethod)
#: d_smpl scale of the `states` goal reward exp(-d / scale): the goal metric's threshold beta (2)
GOAL_REWARD_SCALE = 2.0


class StoredPrompts(Protocol):
    """z's a checkpoint stores by task name (`fbcpr.inference.reward_prompts.RewardPrompts`)."""

    @property
    def z(self) -> dict[str, np.ndarray]: ...

    def zero_shot(self, task: str) -> np.ndarray | None: ...


class PromptableModel(Protocol):
    """What prompting reads of a model (a `BFM`): its sizes, B, the projection and its reward-inference data."""

    @property
    def model(self) -> torch.nn.Module: ...

    @property
    def source(self) -> str | None: ...

    @property
    def obs_dim(self) -> int: ...

    @property
    def z_dim(self) -> int: ...

    @property
    def sequence_length(self) -> int: ...

    @property
    def reward_buffer(self) -> dict[str, np.ndarray] | None: ...

    @property
    def reward_prompts(self) -> StoredPrompts | None: ...

    def reward_samples(self, n: int, seed: int = 0) -> tuple[dict[str, np.ndarray], torch.Tensor]: ...

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: Literal[True]) -> torch.Tensor: ...

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: Literal[False] = False) -> np.ndarray: ...

    @overload
    def backward(self, obs: np.ndarray | torch.Tensor, as_tensor: bool) -> np.ndarray | torch.Tensor: ...

    def project_z(self, z: np.ndarray | torch.Tensor) -> np.ndarray: ...


class Prompt:
    """Latent-z inference for one model (B over its reward-inference buffer is cached by the model)."""

    def __init__(self, bfm: PromptableModel) -> None:
        self.bfm = bfm

    # ----------------------------------------------------------------------------------------- rewards
    def reward(
        self,
        task: RewardSpec,
        method: Literal["weighted", "regression"] = "weighted",
        n: int = N_REWARD_SAMPLES,
        temperature: float = TEMPERATURE,
        seed: int = 0,
        refined: bool = True,
    ) -> np.ndarray:
        """z for a reward: relabel up to n buffer samples (next state) with the reward, then regress on B.

        A named task under these default settings returns the z the checkpoint stores for it, if any: inferred at
        export from every state given, more than the checkpoint keeps, and refined by rollouts for some tasks
        unless `refined` is False (`fbcpr.inference.reward_prompts`)."""
        if method not in ("weighted", "regression"):
            raise PromptError(f"unknown reward inference method {method!r}: use 'weighted' or 'regression'")
        fn, label = reward_fn(task)
        if n < 1:
            raise PromptError(f"number of reward samples must be positive, got {n}")
        if method == "weighted" and not (isinstance(temperature, (int, float)) and np.isfinite(temperature)
                                         and temperature >= 0):
            raise PromptError(f"temperature: must be a finite number >= 0, got {temperature!r}")
        stored = self.stored_reward(task, method, n, temperature, seed, refined)
        if stored is not None:
            return stored
        if self.bfm.reward_buffer is None:
            raise PromptError("this checkpoint ships no reward-inference buffer (reward_buffer.safetensors): "
                              "reward prompts need one; goal, track and imitate prompts still work")
        samples, b = self.bfm.reward_samples(n, seed)
        return self._project(regress_reward(fn, label, samples, b, method, temperature))

    def stored_reward(
        self,
        task: RewardSpec,
        method: str = "weighted",
        n: int = N_REWARD_SAMPLES,
        temperature: float = TEMPERATURE,
        seed: int = 0,
        refined: bool = True,
    ) -> np.ndarray | None:
        """The z the checkpoint stores for a named task (`fbcpr.inference.reward_prompts`), which `reward` returns under
        these default settings (its zero-shot z when `refined` is False); None for other settings, a callable, a
        combined or unstored name, or no stored prompts."""
        stored = self.bfm.reward_prompts
        if stored is None or not isinstance(task, str) or (method, n, temperature, seed) != (
                "weighted", N_REWARD_SAMPLES, TEMPERATURE, 0):
            return None
        z = stored.z.get(task.strip()) if refined else stored.zero_shot(task.strip())
        return None if z is None else z.copy()

    # ------------------------------------------------------------------------------------------- goals
    def goal(self, target: GoalSpec, method: GoalMethod = "backward") -> np.ndarray:
        """z for a goal name, a qpos pose (velocities set to zero) or an observation: B(g) (`backward`), the goal as
        a reward on the states the model visited (`states`), or both (`mix`)."""
        if method not in GOAL_METHODS:
            raise PromptError(f"unknown goal inference method {method!r}: use one of {', '.join(GOAL_METHODS)}")
        obs = goal_observation(target, self.bfm.obs_dim)
        if method == "backward":
            return self._project(self.bfm.backward(obs, as_tensor=True)[0])
        if self.bfm.reward_buffer is None:
            raise PromptError(f"goal method {method!r} infers z from the checkpoint's reward-inference buffer, and "
                              "this checkpoint ships none: use method 'backward'")
        z_states = self.reward(goal_reward(obs[0]))
        if method == "states":
            return z_states
        z_pose = self._project(self.bfm.backward(obs, as_tensor=True)[0])
        return self._project(torch.as_tensor(z_pose) + torch.as_tensor(z_states))

    # ---------------------------------------------------------------------------------------- motions
    def track(self, motion: MotionSpec, refine: int | Receding = 0, num_threads: int | None = None) -> np.ndarray:
        """(T-1, d): one z per step t, the ER_FB of the next L states s_{t+1..t+L}, clipped at the clip end.

        `refine` N > 0 (or a `Receding` of settings) refines them by a receding-horizon search with the simulator,
        N candidates a round, from the clip's first state (`fbcpr.inference.track_refine`): a clip is needed then,
        not bare observations. `track_refined` returns the whole record (trajectory, costs, compute time)."""
        if not isinstance(refine, Receding) and refine == 0:
            obs = motion_observations(motion, self.bfm.obs_dim, min_length=2)
            b = self.bfm.backward(obs, as_tensor=True).double()
            return self._project(tracking_sums(b, self.bfm.sequence_length)[:-1])
        return self.track_refined(motion, refine, num_threads).zs

    def track_refined(self, motion: MotionSpec, refine: int | Receding | None = None,
                      num_threads: int | None = None,
                      on_window: Callable[[int, int], None] | None = None) -> TrackRefined:
        """The B-given tracking z's refined by rollouts from the clip's first state; `refine` is the number of
        candidates a round or a `Receding` of all the settings (None: its defaults; `fbcpr.inference.track_refine`).
        `on_window(done, total)` after every window (a progress bar)."""
        from fbcpr.inference.refine import Policy
        from fbcpr.inference.track_refine import refine_track

        settings = Receding() if refine is None else refine if isinstance(refine, Receding) else None
        if settings is None:
            if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 2:
                raise PromptError(f"refine: the number of candidates a round must be an integer >= 2 (or 0 for "
                                  f"zero-shot), got {refine!r}")
            settings = Receding(candidates=int(refine))
        clip = load_motion(motion) if isinstance(motion, (str, Path)) else motion
        if not (hasattr(clip, "qpos") and hasattr(clip, "qvel")):
            raise PromptError("refine: tracking is refined from the clip's first state, so it needs a Clip or a clip "
                              "file, not bare observations")
        clip = cast("Clip", clip)
        policy = cast(Policy, self.bfm)  # a BFM, which acts as well as it prompts
        alternatives = None
        if settings.lookaheads:  # the tracking z's of other lookahead lengths, as starting centres
            b = self.bfm.backward(clip.obs, as_tensor=True).double()
            alternatives = np.stack([self._project(tracking_sums(b, length)[:-1]) for length in settings.lookaheads])
        return refine_track(policy, clip.obs, (clip.qpos[0], clip.qvel[0]), self.track(clip), settings, num_threads,
                            on_window=on_window, alternatives=alternatives)

    def imitate(self, motion: MotionSpec) -> np.ndarray:
        """One z for a whole motion: ER_FB, the mean of B over all its states."""
        obs = motion_observations(motion, self.bfm.obs_dim, min_length=1)
        return self._project(self.bfm.backward(obs, as_tensor=True).mean(0))

    # ----------------------------------------------------------------------------------- composition
    def mix(self, parts: Sequence[tuple[np.ndarray | torch.Tensor, float]]) -> np.ndarray:
        """Weighted mixture Σ w_i z_i of prompts (e.g. 0.7 walk + 0.3 raise arms), projected to the sphere."""
        if len(parts) == 0:
            raise PromptError("mix needs at least one (z, weight) pair")
        zs = [np.asarray(z.detach().cpu() if isinstance(z, torch.Tensor) else z, dtype=np.float64) for z, _ in parts]
        for z in zs:
            if z.shape != (self.bfm.z_dim,):
                raise PromptError(f"mix: every z must have shape ({self.bfm.z_dim},), got {z.shape}")
        total = sum(float(w) * z for z, (_, w) in zip(zs, parts))
        return self._project(torch.as_tensor(total))

    def _project(self, z: torch.Tensor) -> np.ndarray:
        """Onto the sqrt(d) sphere; a zero or non-finite z is an error, never a silent NaN."""
        z = z.double()
        norm = torch.linalg.vector_norm(z, dim=-1)
        if not torch.all(torch.isfinite(z)) or torch.any(norm == 0):
            raise PromptError("the prompt produced a zero or non-finite z (degenerate input)")
        return self.bfm.project_z(z.float())


def regress_reward(fn: Callable[..., np.ndarray], label: str, samples: dict[str, np.ndarray], b: torch.Tensor,
                   method: Literal["weighted", "regression"], temperature: float) -> torch.Tensor:
    """Σ_i w_i B(s_i) for the reward `fn` on `samples` (next_obs, qpos, qvel) whose B rows are `b`; PromptError
    names the reward `label` when it fails, returns a wrong shape or NaN, or pays nothing on any sample."""
    try:
        r = fn(samples["next_obs"], None, samples["qpos"], samples["qvel"])
    except Exception as err:  # reward code errors are reported with the reward's name
        raise PromptError(f"reward {label!r} failed on the reward-inference buffer: {err}") from err
    r = np.asarray(r, dtype=np.float64)
    if r.shape != (b.shape[0],):
        raise PromptError(f"reward {label!r} returned shape {r.shape}, expected ({b.shape[0]},)")
    if not np.all(np.isfinite(r)):
        raise PromptError(f"reward {label!r} returned non-finite values on the reward-inference buffer")
    w = reward_weights(torch.as_tensor(r), temperature if method == "weighted" else None)
    if not torch.any(w != 0):
        raise PromptError(
            f"reward {label!r} is zero on all {r.shape[0]} buffer samples: the buffer holds no state it "
            "rewards, so there is nothing to infer z from"
        )
    return w.to(dtype=b.dtype, device=b.device) @ b


def goal_reward(goal_obs: np.ndarray, scale: float = GOAL_REWARD_SCALE) -> Callable[..., np.ndarray]:
    """r(s') = exp(-d_smpl(s', g) / scale): 1 at the goal pose, and it falls off with the goal metric's distance."""
    from fbcpr.metrics import d_smpl

    def goal_proximity_reward(next_obs: np.ndarray, *_: object) -> np.ndarray:
        return np.exp(-d_smpl(next_obs, goal_obs) / scale)

    return goal_proximity_reward


def goal_observation(target: GoalSpec, obs_dim: int) -> np.ndarray:
    """(1, obs_dim) observation of a goal given by name, by qpos (76,) with zero velocities, or as an observation."""
    from humanoid_env.model import NQ, NV, load_model
    from humanoid_env.observation import observe

    if isinstance(target, str):
        from humanoid_env.tasks.goals import goal_obs

        try:
            obs = goal_obs(target)
        except (KeyError, ValueError) as err:
            raise PromptError(err.args[0] if err.args else str(err)) from err  # names the goal
    else:
        arr = np.asarray(target.detach().cpu() if isinstance(target, torch.Tensor) else target, dtype=np.float64)
        if arr.shape == (NQ,):
            obs = observe(load_model(), arr, np.zeros(NV))
        elif arr.shape == (obs_dim,):
            obs = arr
        else:
            raise PromptError(
                f"a goal is a name, a qpos of shape ({NQ},) or an observation of shape ({obs_dim},); "
                f"got shape {arr.shape}"
            )
    obs = np.asarray(obs, dtype=np.float32).reshape(1, -1)
    if obs.shape[1] != obs_dim or not np.all(np.isfinite(obs)):
        raise PromptError(f"goal observation must be {obs_dim} finite values, got shape {obs.shape[1:]}")
    return obs


def builtin_clip_names() -> list[str]:
    """Names of the built-in synthetic clips (stand, walk, ...), usable wherever a clip file is."""
    from motions.synthetic import default_clips

    return [c.name for c in default_clips()]


def load_motion(spec: str | Path) -> Clip:
    """A clip from an .npz file, or a built-in synthetic clip by name; errors name the file or list the names."""
    from motions.clip import ClipFormatError, load_clip

    path = Path(spec)
    if path.is_file():
        try:
            return load_clip(path)
        except ClipFormatError as err:
            raise PromptError(str(err)) from None
    if path.is_dir():
        names = sorted(p.name for p in path.glob("*.npz"))
        inside = f"pick one of its {len(names)} clips: {', '.join(names[:8])}{', ...' if len(names) > 8 else ''}" \
            if names else "it holds no clip .npz files"
        raise PromptError(f"{path}: is a directory, not a clip; {inside}")
    if path.suffix == "" and path.parent == Path("."):
        from motions.synthetic import default_clips

        for clip in default_clips():
            if clip.name == str(spec):
                return clip
        raise PromptError(f"motion {str(spec)!r}: no such clip file, nor a built-in clip "
                          f"({', '.join(builtin_clip_names())})")
    raise PromptError(f"motion clip not found: {path}")


def motion_observations(motion: MotionSpec, obs_dim: int, min_length: int) -> np.ndarray:
    """(T, obs_dim) float32 observations of a Clip, a clip file or an array, checked for shape, length and NaN."""
    if isinstance(motion, (str, Path)):
        motion = load_motion(motion)
    obs = getattr(motion, "obs", motion)
    arr = np.asarray(obs.detach().cpu() if isinstance(obs, torch.Tensor) else obs, dtype=np.float32)
    name = getattr(motion, "name", "motion")
    if arr.ndim != 2 or arr.shape[1] != obs_dim:
        raise PromptError(f"{name}: expected observations of shape (T, {obs_dim}), got {arr.shape}")
    if arr.shape[0] < min_length:
        raise PromptError(f"{name}: clip too short ({arr.shape[0]} frames, need at least {min_length})")
    if not np.all(np.isfinite(arr)):
        raise PromptError(f"{name}: observations contain NaN or inf")
    return arr
