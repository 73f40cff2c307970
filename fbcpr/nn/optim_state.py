"""Adam as a learner builds it (one fused kernel per parameter group), and its state as flat safetensors entries plus
JSON, the form every agent's `state()` writes (no pickles)."""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import torch
from torch import Tensor

#: Optimiser settings that say how a step is computed rather than what it computes: a loaded state keeps the
#: optimiser's own (a checkpoint written by another implementation loads into this one).
IMPLEMENTATION = ("fused", "foreach", "capturable")


def fused_adam(params: Iterable[Tensor], lr: float, capturable: bool = False) -> torch.optim.Adam:
    """Adam whose step is one fused kernel for all of `params` (torch's single-tensor Adam on the CPU launches nine per
    parameter). The same update as torch's reference Adam to float32 rounding; `capturable`: its step counters live on
    the device, as a CUDA graph needs (`fbcpr.nn.cuda_graph`)."""
    return torch.optim.Adam(params, lr=lr, betas=(0.9, 0.999), eps=1e-8, fused=True, capturable=capturable)


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
    """Inverse of `optimizer_state`; KeyError / ValueError when the entries do not fit the optimiser. The optimiser
    keeps its own `IMPLEMENTATION` settings, and a fused or capturable one its step counters on its parameters'
    device."""
    state = {int(idx): {key: tensors[f"{prefix}.{idx}.{key}"] for key in keys}
             for idx, keys in meta["state_keys"].items()}
    built = [{k: g[k] for k in IMPLEMENTATION if k in g} for g in opt.param_groups]
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    for group, settings in zip(opt.param_groups, built):
        group.update(settings)
        if group.get("fused") or group.get("capturable"):
            for p in group["params"]:
                st = opt.state.get(p, {})
                if "step" in st:
                    st["step"] = st["step"].to(p.device, torch.float32)
