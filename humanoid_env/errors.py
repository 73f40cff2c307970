"""The environment package's error types: bad arguments, states and actions end in an `EnvError`.

`EnvError` derives from ValueError, what Gymnasium code expects of a bad value, so existing handlers keep working.
"""
from __future__ import annotations


class EnvError(ValueError):
    """A bad argument or option given to an environment; the message names it."""


class InvalidActionError(EnvError):
    """An action that is not a finite array of numbers of the expected shape; the message names the action."""


class InvalidStateError(EnvError):
    """A state (qpos, qvel) given to reset, or sampled by an init, of the wrong shape or not finite."""
