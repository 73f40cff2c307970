"""Adam state as flat safetensors entries plus JSON, the form every agent's `state()` writes (no pickles)."""
from __future__ import annotations

from typing import Any

import torch
from torch import Tensor


def optimizer_state(opt: torch.optim.Optimizer, prefix: str, tensors: dict[str, Tensor]) -> dict[str, Any]:
    """Put the optimiser's tensors into `tensors` as `{prefix}.{param}.{key}`; return the JSON part."""
    sd = opt.state_dict()
    meta: dict[str, Any] = {"param_groups": sd["param_groups"], "state_keys": {}}
    for idx, st in sd["state"].items():
        meta["state_keys"][str(idx)] = sorted(st)
        for key, val in st.items():
            tensors[f"{prefix}.{idx}.{key}"] = torch.as_tensor(val)
    return meta


def load_optimizer_state(opt: torch.optim.Optimizer, prefix: str, meta: dict[str, Any],
                         tensors: dict[str, Tensor]) -> None:
    """Inverse of `optimizer_state`; KeyError / ValueError when the entries do not fit the optimiser."""
    state = {int(idx): {key: tensors[f"{prefix}.{idx}.{key}"] for key in keys}
             for idx, keys in meta["state_keys"].items()}
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
