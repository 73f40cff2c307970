"""The one reward registry: paper task names (App. C.3.1, Tables 18 and 25) -> vectorized reward functions.

Every reward is a function of the *next* observation only (heading-frame body quantities, see
`humanoid_env.tasks.features`), shaped with dm_control's `rewards.tolerance` and bounded to [0, 1]. Actions,
qpos and qvel are accepted (the contract's signature) but unused, so a reward relabels a buffer that stores
only next observations exactly as it scores a live episode. Formulas and thresholds: docs/tasks.md.
"""
from __future__ import annotations

import difflib
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from humanoid_env.tasks.features import Features, as_obs_batch


class RewardFn(Protocol):
    @property
    def name(self) -> str: ...

    def __call__(self, obs: np.ndarray, action: np.ndarray | None = None, qpos: np.ndarray | None = None,
                 qvel: np.ndarray | None = None) -> np.ndarray: ...


# Thresholds for our 1.7 m body (head origin 1.57 m, shoulders 1.43 m, pelvis 0.965 m when standing).
STAND_HEAD = 1.4          # head height that counts as standing
LOW_PELVIS = (0.45, 0.7)  # pelvis band for low locomotion
SIT_HEAD = 0.58           # head height of an upright seat on the floor
JUMP_SPEED = 5.0          # vertical centre-of-mass speed (m/s) at which the jump reward saturates
ARM_BANDS = {"l": (0.0, 1.0, 0.2), "m": (1.3, 1.55, 0.1), "h": (1.8, np.inf, 0.2)}  # wrist z (lo, hi, margin)


def _tol(x: np.ndarray, lo: float, hi: float, margin: float, sigmoid: str = "linear",
         at_margin: float = 0.0) -> np.ndarray:
    # Imported here, not at the top: the training path names tasks (train.eval_tasks, checked by the config) without
    # computing rewards, and must run where dm_control is absent (a minimal GPU image, tests/test_training_deps.py).
    from dm_control.utils.rewards import tolerance

    return tolerance(x, bounds=(lo, hi), margin=margin, sigmoid=sigmoid, value_at_margin=at_margin)


def _standing(f: Features) -> np.ndarray:
    """Head above STAND_HEAD; linearly 0 at half that height (sitting on the floor)."""
    return _tol(f.z("Head"), STAND_HEAD, np.inf, STAND_HEAD / 2)


def _upright(f: Features, lo: float = 0.9, margin: float | None = None) -> np.ndarray:
    """Chest z-axis pointing up: 1 above `lo`, linearly 0 at `lo - margin` (default: upside down)."""
    return _tol(f.axis_z("Chest")[:, 2], lo, np.inf, lo + 1.0 if margin is None else margin)


def _still(f: Features, band: float = 0.2) -> np.ndarray:
    return _tol(f.com_speed_xy, 0.0, band, 1.0)


def _unit_xy(v: np.ndarray) -> np.ndarray:
    xy = v[:, :2].astype(np.float64)
    norm = np.linalg.norm(xy, axis=1, keepdims=True)
    return np.where(norm > 1e-6, xy / np.maximum(norm, 1e-6), np.array([1.0, 0.0]))


def _move(f: Features, direction: np.ndarray, speed: float) -> np.ndarray:
    """Horizontal centre-of-mass velocity in a band around `speed` along `direction` (N, 2 unit vectors)."""
    v = f.com_vel[:, :2].astype(np.float64)
    if speed == 0:
        return _tol(np.linalg.norm(v, axis=1), 0.0, 0.1, 1.0)
    along = (v * direction).sum(1)
    across = np.abs(v[:, 0] * direction[:, 1] - v[:, 1] * direction[:, 0])
    band = 0.1 * speed
    return _tol(along, speed - band, speed + band, speed) * _tol(across, 0.0, band, speed)


def _rotate_xy(d: np.ndarray, degrees: float) -> np.ndarray:
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=1)


class _Reward:
    """Shared validation and the RewardFn call signature; subclasses implement `compute(Features)` and `name` (a
    property or a dataclass field)."""

    #: times this formula was revised after its first release: prompts stored for a task record it, so a prompt
    #: inferred for an older formula is known to be stale (`fbcpr.inference.reward_prompts`)
    revision: ClassVar[int] = 0

    @property
    def name(self) -> str:
        raise NotImplementedError

    def revisions(self) -> dict[str, int]:
        """The revised formulas this reward is made of, by term name; empty while every term is as first released."""
        return {self.name: self.revision} if self.revision else {}

    def compute(self, f: Features) -> np.ndarray:
        raise NotImplementedError

    def __call__(self, obs: np.ndarray, action: np.ndarray | None = None, qpos: np.ndarray | None = None,
                 qvel: np.ndarray | None = None) -> np.ndarray:
        arr = np.asarray(obs)
        flat = as_obs_batch(arr, f"reward {self.name!r}")
        out = np.clip(self.compute(Features(flat)), 0.0, 1.0).astype(np.float32)
        return out.reshape(arr.shape[:-1])


@dataclass(frozen=True)
class Move(_Reward):
    """Locomotion at `speed` m/s, `angle` degrees left of the chest's facing; standing tall or low."""

    angle: float
    speed: float
    low: bool = False

    @property
    def name(self) -> str:
        return f"move-ego-{'low-' if self.low else ''}{_fmt(self.angle)}-{_fmt(self.speed)}"

    def compute(self, f: Features) -> np.ndarray:
        if self.low:
            height = _tol(f.z("Pelvis"), *LOW_PELVIS, 0.35) * _upright(f, lo=0.5)
        else:
            height = _standing(f) * _upright(f)
        direction = _rotate_xy(_unit_xy(f.axis_x("Chest")), self.angle)
        return height * _move(f, direction, self.speed)


@dataclass(frozen=True)
class Jump(_Reward):
    """Head above `height` m, paid in proportion to the centre of mass's upward speed up to JUMP_SPEED.

    Revision 1: the speed term was `tol(v_z, 0.5, inf, 0.5)`, which paid a body bobbing on its knees in full on
    every rise. Take-offs of real jumps reach 2-3 m/s, so a linear term to 5 m/s (the paper's reference reward)
    never saturates on them and pays a faster take-off more.
    """

    revision: ClassVar[int] = 1
    height: float

    @property
    def name(self) -> str:
        return f"jump-{_fmt(self.height)}"

    def compute(self, f: Features) -> np.ndarray:
        up = _tol(f.z("Head"), self.height, np.inf, self.height / 2)
        rising = _tol(f.com_vel[:, 2], JUMP_SPEED, np.inf, JUMP_SPEED)
        return _upright(f) * up * rising


@dataclass(frozen=True)
class Rotate(_Reward):
    """Spin at `speed` rad/s about the pelvis's own `axis`, that axis kept horizontal (x, y) or vertical (z),
    with the pelvis above `height` m."""

    axis: str
    speed: float
    height: float

    @property
    def name(self) -> str:
        return f"rotate-{self.axis}-{_fmt(self.speed)}-{_fmt(self.height)}"

    def compute(self, f: Features) -> np.ndarray:
        k = "xyz".index(self.axis)
        w = f.local_angvel("Pelvis")[:, k]
        x, zax = f.axis_x("Pelvis"), f.axis_z("Pelvis")
        axis_world_z = (x[:, 2], np.cross(zax, x)[:, 2], zax[:, 2])[k]
        align = _tol(axis_world_z, 0.9, np.inf, 1.9) if self.axis == "z" else _tol(np.abs(axis_world_z), 0.0, 0.1, 0.9)
        band = 0.1 * abs(self.speed)
        spin = _tol(w, self.speed - band, self.speed + band, abs(self.speed))
        return _tol(f.z("Pelvis"), self.height, np.inf, self.height) * align * spin


@dataclass(frozen=True)
class RaiseArms(_Reward):
    """Stand with each wrist in a height band: l (hanging), m (shoulder height), h (above the head). Moving the
    body around halves the reward (a penalty for needless movement, not a gate), unless `calm` is off, as in
    the locomotion + arms composites of Table 25."""

    left: str
    right: str
    calm: bool = True

    @property
    def name(self) -> str:
        return f"raisearms-{self.left}-{self.right}"

    def compute(self, f: Features) -> np.ndarray:
        arms = np.ones(f.obs.shape[0])
        for side, level in (("L", self.left), ("R", self.right)):
            lo, hi, margin = ARM_BANDS[level]
            arms = arms * _tol(f.z(f"{side}_Wrist"), lo, hi, margin, "gaussian", 0.1)
        calm = (1.0 + _still(f)) / 2 if self.calm else 1.0
        return _standing(f) * _upright(f) * arms * calm


@dataclass(frozen=True)
class Crouch(_Reward):
    """Squat: pelvis low (between `min_height` and 0.6 m) and above the feet, feet on the floor, knees off it,
    torso upright, still.

    Revision 1: the pelvis margin was 0.4 m, which paid a body standing on bent knees (pelvis 0.8 m) half.
    """

    revision: ClassVar[int] = 1
    min_height: float

    @property
    def name(self) -> str:
        return f"crouch-{_fmt(self.min_height)}"

    def compute(self, f: Features) -> np.ndarray:
        low = _tol(f.z("Pelvis"), self.min_height, 0.6, 0.15)
        feet = _tol(np.maximum(f.z("L_Ankle"), f.z("R_Ankle")), 0.0, 0.15, 0.3)
        ankles_xy = (f.rel("L_Ankle")[:, :2] + f.rel("R_Ankle")[:, :2]) / 2
        over_feet = _tol(np.linalg.norm(ankles_xy, axis=1), 0.0, 0.3, 0.3)
        knees_up = _tol(np.minimum(f.z("L_Knee"), f.z("R_Knee")), 0.25, np.inf, 0.15)
        return low * feet * over_feet * knees_up * _upright(f, lo=0.8, margin=0.8) * _still(f)


@dataclass(frozen=True)
class SitOnGround(_Reward):
    """Sit on the floor (kneel-sit or legs forward): both knees on the floor, pelvis below 0.5 m, torso upright,
    head up (a body curled over its knees is not sitting: the paper's reference reward asks the head 0.58 m up),
    still."""

    name: str = "sitonground"
    revision: ClassVar[int] = 1  # the head term

    def compute(self, f: Features) -> np.ndarray:
        knees = _tol(np.maximum(f.z("L_Knee"), f.z("R_Knee")), 0.0, 0.12, 0.3)
        low = _tol(f.z("Pelvis"), 0.0, 0.5, 0.4)
        head = _tol(f.z("Head"), SIT_HEAD, np.inf, 0.1)
        return knees * low * head * _upright(f, lo=0.7, margin=0.7) * _still(f)


@dataclass(frozen=True)
class LieOnGround(_Reward):
    """Lie flat, chest facing the sky (`up`) or the floor (`down`), still."""

    facing: str

    @property
    def name(self) -> str:
        return f"lieonground-{self.facing}"

    def compute(self, f: Features) -> np.ndarray:
        sign = 1.0 if self.facing == "up" else -1.0
        face = _tol(sign * f.axis_x("Chest")[:, 2], 0.8, np.inf, 1.8)
        low = _tol(f.z("Pelvis"), 0.0, 0.25, 0.5) * _tol(f.z("Head"), 0.0, 0.3, 0.6)
        return face * low * _still(f)


@dataclass(frozen=True)
class Split(_Reward):
    """Pelvis low (below 0.5 m) with the ankles at least `distance` m apart, torso upright, still."""

    distance: float

    @property
    def name(self) -> str:
        return f"split-{_fmt(self.distance)}"

    def compute(self, f: Features) -> np.ndarray:
        gap = np.linalg.norm((f.rel("L_Ankle") - f.rel("R_Ankle"))[:, :2], axis=1)
        apart = _tol(gap, self.distance, np.inf, self.distance)
        low = _tol(f.z("Pelvis"), 0.0, 0.5, 0.5)
        return apart * low * _upright(f, lo=0.5, margin=0.5) * _still(f)


@dataclass(frozen=True)
class Crawl(_Reward):
    """Spine at `height` m (+-0.1), trunk near horizontal with the belly facing the floor (`d`) or the sky (`u`),
    moving head-first at `speed`."""

    height: float
    speed: float
    facing: str

    @property
    def name(self) -> str:
        return f"crawl-{_fmt(self.height)}-{_fmt(self.speed)}-{self.facing}"

    def compute(self, f: Features) -> np.ndarray:
        level = _tol(f.z("Spine"), self.height - 0.1, self.height + 0.1, 0.2)
        sign = -1.0 if self.facing == "d" else 1.0
        face = _tol(sign * f.axis_x("Chest")[:, 2], 0.7, np.inf, 0.5)
        flat = _tol(np.abs(f.axis_z("Chest")[:, 2]), 0.0, 0.5, 0.5)
        head_first = _unit_xy(f.axis_z("Chest"))
        return level * face * flat * _move(f, head_first, self.speed)


@dataclass(frozen=True)
class Handstand(_Reward):
    """Upside down on the hands: feet highest (above 1.5 m), head low, body still."""

    name: str = "handstand"

    def compute(self, f: Features) -> np.ndarray:
        feet = _tol(np.minimum(f.z("L_Ankle"), f.z("R_Ankle")), 1.5, np.inf, 1.0)
        head = _tol(f.z("Head"), 0.0, 0.7, 0.7)
        spin = _tol(np.linalg.norm(f.angvel("Pelvis"), axis=1), 0.0, 0.5, 2.0)
        return feet * head * _still(f) * spin


@dataclass(frozen=True)
class Headstand(_Reward):
    """Upside down on the head: head on the floor, feet above 1.4 m, body still."""

    name: str = "headstand"

    def compute(self, f: Features) -> np.ndarray:
        feet = _tol(np.minimum(f.z("L_Ankle"), f.z("R_Ankle")), 1.4, np.inf, 1.0)
        head = _tol(f.z("Head"), 0.0, 0.2, 0.5)
        spin = _tol(np.linalg.norm(f.angvel("Pelvis"), axis=1), 0.0, 0.5, 2.0)
        return feet * head * _still(f) * spin


@dataclass(frozen=True)
class HeadHeight(_Reward):
    """Head at or above `height` m, linearly from 0 with the head on the floor: not a task of the paper but a
    reward for getting up, in which no posture on the floor pays more than a higher one (a reward that pays for
    floor postures holds a single-task agent on the floor)."""

    height: float

    @property
    def name(self) -> str:
        return f"head-{_fmt(self.height)}"

    def compute(self, f: Features) -> np.ndarray:
        return _tol(f.z("Head"), self.height, np.inf, self.height)


@dataclass(frozen=True)
class _Combined(_Reward):
    """A reward made of other rewards' terms."""

    terms: tuple[_Reward, ...]

    def revisions(self) -> dict[str, int]:
        return {k: v for t in self.terms for k, v in t.revisions().items()}


@dataclass(frozen=True)
class Product(_Combined):
    """All terms at once: the product of their values (written `a*b`)."""

    @property
    def name(self) -> str:
        return "*".join(t.name for t in self.terms)

    def compute(self, f: Features) -> np.ndarray:
        out = np.ones(f.obs.shape[0])
        for t in self.terms:
            out = out * t.compute(f)
        return out


@dataclass(frozen=True)
class Mean(_Combined):
    """Either term: the mean of their values (written `a+b`)."""

    @property
    def name(self) -> str:
        return "+".join(t.name for t in self.terms)

    def compute(self, f: Features) -> np.ndarray:
        return np.asarray(sum(t.compute(f) for t in self.terms)) / len(self.terms)


@dataclass(frozen=True)
class MoveAndRaiseArms(Product):
    """Table 25's composite tasks, `move-ego-{angle}-{speed}-raisearms-{l}-{r}`: locomotion times arm raising
    (without the arms' movement penalty, since the task is to move)."""

    @property
    def name(self) -> str:
        return f"{self.terms[0].name}-{self.terms[1].name}"


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


_NUM = r"\d+(?:\.\d+)?"
_SNUM = rf"-?{_NUM}"

#: family pattern shown to users -> (full-match regex, constructor from the match groups)
FAMILIES: dict[str, tuple[re.Pattern[str], Callable[..., _Reward]]] = {
    "move-ego-{angle}-{speed}-raisearms-{l|m|h}-{l|m|h}": (
        re.compile(rf"move-ego-({_SNUM})-({_NUM})-raisearms-([lmh])-([lmh])"),
        lambda a, s, left, right: MoveAndRaiseArms((Move(float(a), float(s)), RaiseArms(left, right, calm=False))),
    ),
    "move-ego-{angle}-{speed}": (re.compile(rf"move-ego-({_SNUM})-({_NUM})"), lambda a, s: Move(float(a), float(s))),
    "move-ego-low-{angle}-{speed}": (
        re.compile(rf"move-ego-low-({_SNUM})-({_NUM})"), lambda a, s: Move(float(a), float(s), low=True)),
    "jump-{height}": (re.compile(rf"jump-({_NUM})"), lambda h: Jump(float(h))),
    "rotate-{x|y|z}-{speed}-{height}": (
        re.compile(rf"rotate-([xyz])-({_SNUM})-({_NUM})"), lambda ax, s, h: Rotate(ax, float(s), float(h))),
    "raisearms-{l|m|h}-{l|m|h}": (re.compile(r"raisearms-([lmh])-([lmh])"), RaiseArms),
    "crouch-{min_pelvis_height}": (re.compile(rf"crouch-({_NUM})"), lambda h: Crouch(float(h))),
    "sitonground": (re.compile(r"sitonground"), SitOnGround),
    "lieonground-{up|down}": (re.compile(r"lieonground-(up|down)"), LieOnGround),
    "split-{distance}": (re.compile(rf"split-({_NUM})"), lambda d: Split(float(d))),
    "crawl-{height}-{speed}-{u|d}": (
        re.compile(rf"crawl-({_NUM})-({_NUM})-([ud])"), lambda h, s, face: Crawl(float(h), float(s), face)),
    "handstand": (re.compile(r"handstand"), Handstand),
    "headstand": (re.compile(r"headstand"), Headstand),
    "head-{height}": (re.compile(rf"head-({_NUM})"), lambda h: HeadHeight(float(h))),
}


def list_families() -> list[str]:
    """Name patterns the registry understands (plus `a*b` products and `a+b` means of them)."""
    return list(FAMILIES)


def _unknown(name: str, why: str) -> ValueError:
    close = difflib.get_close_matches(name, TASKS, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return ValueError(f"{why} {name!r}{hint}. Known families: {', '.join(FAMILIES)}; combine with '*' (product) "
                      f"or '+' (mean), e.g. 'move-ego-0-2*raisearms-h-h'; `fbcpr tasks` lists them all")


def _parse_single(name: str) -> _Reward:
    for pattern, build in FAMILIES.values():
        m = pattern.fullmatch(name)
        if m:
            return build(*m.groups())
    raise _unknown(name, "unknown reward task")


def get_reward(name: str) -> _Reward:
    """The reward function for a task name such as `move-ego-45-3`, `smpl_jump-2` or `a*b+c`.

    `*` binds tighter than `+`: `a*b+c` is the mean of (a times b) and c.
    """
    if not isinstance(name, str) or not name.strip():
        raise _unknown(str(name), "empty reward task name")
    text = name.strip().replace(" ", "")
    means = []
    for part in text.split("+"):
        pieces = part.split("*") if part else []
        if not pieces or not all(pieces):  # 'jump-2*', '+a', 'a**b': a term left empty
            raise _unknown(name, "malformed reward expression (a term beside '*' or '+' is empty):")
        factors = []
        for piece in pieces:
            try:
                factors.append(_parse_single(piece.removeprefix("smpl_")))
            except ValueError as err:
                if piece == text:
                    raise
                raise ValueError(f"in {name!r}: {err}") from None
        means.append(factors[0] if len(factors) == 1 else Product(tuple(factors)))
    return means[0] if len(means) == 1 else Mean(tuple(means))


_LOCO = ["move-ego-0-2", "move-ego-0-4", "move-ego-90-2", "move-ego-90-4", "move-ego--90-2", "move-ego--90-4",
         "move-ego-180-2", "move-ego-180-4"]
_LOCO_LOW = ["move-ego-low-0-2", "move-ego-low-90-2", "move-ego-low--90-2", "move-ego-low-180-2"]
_ARMS = [f"raisearms-{a}-{b}" for a in "lmh" for b in "lmh"]

#: Task -> category, for every task of the paper's Table 18 (categories of Table 19) and Table 25 (composite).
CATEGORIES: dict[str, str] = {
    **{t: "Stand" for t in ["move-ego-0-0", "move-ego-low-0-0"]},
    "handstand": "Handstand",
    **{t: "Locomotion" for t in _LOCO},
    **{t: "LocomLow" for t in _LOCO_LOW},
    "jump-2": "Jump",
    **{f"rotate-{ax}-{s}-0.8": "Rotation" for ax in "xyz" for s in ("5", "-5")},
    **{t: "RaiseArms" for t in _ARMS},
    **{t: "On-Ground" for t in ["crouch-0", "sitonground", "lieonground-up", "lieonground-down", "split-0.5",
                                 "split-1"]},
    **{f"crawl-{h}-{s}-{face}": "Crawl" for face in "ud" for h in ("0.4", "0.5") for s in ("0", "2")},
    **{f"move-ego-0-2-{t}": "Composite" for t in _ARMS},
}
#: Every task name of Tables 18 and 25, in table order.
TASKS: tuple[str, ...] = tuple(CATEGORIES)


def task_category(name: str) -> str:
    """Table 19 category of a task; parameterized names outside the tables get their family's category."""
    if name in CATEGORIES:
        return CATEGORIES[name]
    reward = get_reward(name)
    by_type = {Move: "Locomotion", Jump: "Jump", Rotate: "Rotation", RaiseArms: "RaiseArms", Crouch: "On-Ground",
               SitOnGround: "On-Ground", LieOnGround: "On-Ground", Split: "On-Ground", Crawl: "Crawl",
               Handstand: "Handstand", Headstand: "Handstand", HeadHeight: "Stand", MoveAndRaiseArms: "Composite"}
    if isinstance(reward, Move):
        return ("LocomLow" if reward.low else "Locomotion") if reward.speed else "Stand"
    return by_type.get(type(reward), "Composite")
