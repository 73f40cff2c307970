"""What a reward prompt accepts: a registry name (combined names included) or a callable, resolved to a RewardFn.

Apart from `fbcpr.inference.prompt` so that rollout refinement (`fbcpr.inference.refine`), which the prompts call for
tracking, reads it without an import cycle."""
from __future__ import annotations

from collections.abc import Callable
from typing import Union

import numpy as np

from fbcpr.core.errors import PromptError

#: A reward given by registry name (e.g. "jump-2", "move-ego-0-2*crouch-0") or as a RewardFn-like callable.
RewardSpec = Union[str, Callable[..., np.ndarray]]


def reward_fn(task: RewardSpec) -> tuple[Callable[..., np.ndarray], str]:
    """The RewardFn for a registry name (combined names included) or a user callable, with a label for errors."""
    if callable(task):
        return task, getattr(task, "__name__", repr(task))
    if not isinstance(task, str) or not task.strip():
        raise PromptError(f"a reward is a task name or a callable, got {task!r}")
    from humanoid_env.tasks import get_reward

    try:
        return get_reward(task.strip()), task.strip()
    except (KeyError, ValueError) as err:
        raise PromptError(err.args[0] if err.args else str(err)) from err  # the registry's message names the task
