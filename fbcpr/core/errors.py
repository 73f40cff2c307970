"""The package's error types: every bad input a user can hand to `fbcpr` ends in one of them.

`FBCPRError` is the one base to catch. Each subclass also derives from the built-in exception a caller would
otherwise expect (ValueError for bad values, RuntimeError for a checkpoint that cannot be read or written), so
code written against the built-ins keeps working. Kept free of torch and numpy so `fbcpr.core.config` stays cheap.
"""
from __future__ import annotations


class FBCPRError(Exception):
    """Base of every error `fbcpr` raises on purpose; the message names the file, key or argument at fault."""


class InputError(FBCPRError, ValueError):
    """An array or argument handed to the public API (observations, latents, trajectories, options) of the wrong
    shape, type or range, or not finite."""


class ConfigError(FBCPRError, ValueError):
    """A configuration value that is unknown, of the wrong type or out of range; the message names the key."""


class PromptError(FBCPRError, ValueError):
    """A prompt that cannot be turned into a z (unknown task, wrong shape, empty buffer, ...)."""
