"""What a run costs before it starts: the model's and the replay buffer's memory and one checkpoint's disk,
checked against the machine so that a config that cannot fit fails in one line naming the key to lower, not in
an allocation (or the OOM killer) minutes later."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import torch

from fbcpr.core.checkpoint import CheckpointError
from fbcpr.core.errors import ConfigError
from fbcpr.core.registry import get_method
from fbcpr.core.schema import Config
from fbcpr.train.buffer import ReplayBuffer
from fbcpr.train.device_batches import DeviceBatches

#: Bytes per model parameter during training: weights, gradients, two Adam moments and a target copy.
BYTES_PER_PARAMETER = 20


def memory_bytes(device: torch.device) -> int:
    """Total memory of the device the model trains on (RAM for the CPU)."""
    if device.type == "cuda":
        return int(torch.cuda.get_device_properties(device).total_memory)
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_model_memory(cfg: Config, device: torch.device, copies: int = 1) -> tuple[int, int]:
    """(parameters, bytes to train them) of the configured model, counted on the meta device before anything is
    allocated; ConfigError naming the keys to lower when they cannot fit. `copies`: processes of this run on this
    machine (torchrun's ranks), each holding a model."""
    with torch.device("meta"):  # shapes only: no memory is allocated
        model = get_method(cfg.algorithm).model(cfg.model)
    params = sum(p.numel() for p in model.parameters())
    need, have = params * BYTES_PER_PARAMETER, memory_bytes(device)
    if device.type == "cpu":
        need *= copies
    if need > have:
        raise ConfigError(f"model: {params / 1e6:,.0f}M parameters need about {need / 2**30:,.1f} GiB to train, "
                          f"more than the {have / 2**30:,.1f} GiB of {device.type} memory; lower model.hidden_dim, "
                          "model.hidden_layers or model.preset")
    return params, need


def check_memory(cfg: Config, specs: dict[str, tuple[int, ...]], model: tuple[int, int], out: Path,
                 device: torch.device, copies: int = 1) -> bool:
    """The replay buffer's memory beside the model's (`model`: `check_model_memory`'s parameters and bytes), the
    buffer of exactly the fields it will hold (`specs`, a video reward's frames included), checked before the buffer
    is allocated: ConfigError naming the key to lower when they cannot fit, instead of an allocation failing (or the
    OOM killer striking) minutes later; CheckpointError when the disk at `out` cannot hold one checkpoint. `copies`:
    processes of this run on this machine (torchrun's ranks), each holding a model and a replay shard. Returns
    whether the buffer is memory-mapped (over train.buffer_memmap_mb)."""
    tc = cfg.train
    obs_dim = cfg.model.obs_dim
    assert obs_dim is not None, "check_memory: set model.obs_dim first"
    params, need = model
    have = memory_bytes(device)
    nq, nv = specs["qpos"][0], specs["qvel"][0]
    buffer = ReplayBuffer.bytes_needed(tc.buffer_capacity, specs) * copies
    memmap = buffer > tc.buffer_memmap_mb * 2**20
    folder = next(p for p in (out, *out.absolute().parents) if p.exists())
    free = shutil.disk_usage(folder).free
    if memmap and buffer > free:
        raise ConfigError(f"train.buffer_capacity: the memory-mapped replay buffer needs {buffer / 2**30:,.1f} GiB "
                          f"on disk, more than the {free / 2**30:,.1f} GiB free at {folder}")
    # train.device_buffer: the training fields once more, on the device (one copy per rank; on the CPU, in RAM)
    mirror = DeviceBatches.bytes_needed(tc.buffer_capacity, specs, get_method(cfg.algorithm).agent_class().fields) \
        if tc.device_buffer else 0
    if device.type == "cuda" and need + mirror > have:
        raise ConfigError(f"train.device_buffer: the replay batches' copy needs {mirror / 2**30:,.1f} GiB of "
                          f"{device.type} memory beside the model's {need / 2**30:,.1f} GiB, more than its "
                          f"{have / 2**30:,.1f} GiB; lower train.buffer_capacity, or set train.device_buffer: false")
    ram = memory_bytes(torch.device("cpu"))
    model_ram = need if device.type == "cpu" else 0
    if not memmap and buffer + model_ram > ram:
        raise ConfigError(f"train.buffer_capacity: the replay buffer needs {buffer / 2**30:,.1f} GiB of memory, "
                          f"more than the {ram / 2**30:,.1f} GiB this machine has beside the model; lower it, or "
                          "lower train.buffer_memmap_mb to keep it in a memory-mapped file on disk")
    if device.type == "cpu" and (0 if memmap else buffer) + model_ram + mirror * copies > ram:
        raise ConfigError(f"train.device_buffer: its copy of the replay buffer needs {mirror * copies / 2**30:,.1f} "
                          f"GiB of memory beside the buffer and the model, more than the {ram / 2**30:,.1f} GiB this "
                          "machine has; on the CPU the copy only costs memory: set it to false")
    # a full disk fails here, in one line, before TensorBoard's writer thread would fail with a long traceback.
    # One checkpoint: weights, two Adam moments and targets (4 copies), the reward sample, the buffer if saved.
    ckpt = params * 16 + tc.reward_buffer_size * (obs_dim + nq + nv) * 4 + (buffer if tc.save_buffer else 0)
    if ckpt + (buffer if memmap else 0) > free:
        raise CheckpointError(f"{folder}: {free / 2**20:,.0f} MiB free on disk, but one checkpoint of this run needs "
                              f"about {ckpt / 2**20:,.0f} MiB" + (f" beside the {buffer / 2**20:,.0f} MiB "
                              "memory-mapped replay buffer" if memmap else "") + "; free space or choose another --out")
    return memmap


