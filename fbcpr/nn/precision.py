"""Whether bf16 autocast pays on this machine: measured at run time, never assumed.

bf16 GEMMs ran 3x faster than float32 on one of our CPUs and 100x slower on another (no native bf16), so
`agent.bf16: auto` times one update-sized matmul both ways on the training device and takes bf16 only when
it is clearly faster.
"""
from __future__ import annotations

import time

import torch

#: bf16 must beat float32 by this factor to be chosen (autocast adds casts the matmul alone does not show).
MIN_SPEEDUP = 1.3


def matmul_seconds(dtype: torch.dtype, device: torch.device, size: int = 512, repeats: int = 5) -> float:
    """Best-of-`repeats` time of one (size x size) @ (size x size) product in `dtype`."""
    a = torch.randn(size, size, device=device).to(dtype)
    b = torch.randn(size, size, device=device).to(dtype)
    best = float("inf")
    for _ in range(repeats + 1):  # the first run warms up kernels and caches
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t0 = time.perf_counter()
        a @ b
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        best = min(best, time.perf_counter() - t0)
    return best


def resolve_bf16(setting: bool | str, device: torch.device) -> bool:
    """`agent.bf16` to a decision: True/False as given; "auto" = bf16 when its matmul is MIN_SPEEDUP x faster."""
    if isinstance(setting, bool):
        return setting
    speedup = matmul_seconds(torch.float32, device) / matmul_seconds(torch.bfloat16, device)
    return speedup >= MIN_SPEEDUP
