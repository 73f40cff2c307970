"""FB-CPR: a behavioral foundation model for a simulated SMPL humanoid.

`from fbcpr import BFM, Prompt, Timeline` imports torch lazily, so `import fbcpr` alone stays cheap.
"""
from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
__all__ = ["BFM", "FBCPRError", "Prompt", "Timeline", "__version__"]

_LAZY = {"BFM": "fbcpr.inference.bfm", "FBCPRError": "fbcpr.core.errors", "Prompt": "fbcpr.inference.prompt",
         "Timeline": "fbcpr.inference.timeline"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'fbcpr' has no attribute {name!r}")
