"""Optional dependencies: a feature that needs an extra (`pip install "fbcpr[play]"`) imports it through `require`,
so a missing one ends in one line naming the extra rather than a traceback deep inside the feature."""
from __future__ import annotations

import importlib
from types import ModuleType

from fbcpr.core.errors import FBCPRError


class MissingExtraError(FBCPRError, ImportError):
    """A feature's optional dependency is not installed; the message names the extra that installs it."""


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import `module`, or raise MissingExtraError saying that `feature` needs `pip install "fbcpr[extra]"`."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise MissingExtraError(f"{feature} needs the {module!r} package ({err.name or module} is missing): "
                                f"pip install \"fbcpr[{extra}]\"") from None
