"""The policy and B for apps that do not run torch (a game engine, a robot stack, a browser): ONNX graphs and a JSON.

    OUT/actor.onnx       obs (N, obs_dim), z (N, z_dim) -> action (N, action_dim) in [-1, 1], as `BFM.act(obs, z)`:
                         the observation normaliser and the projection of z onto the sqrt(z_dim) sphere are inside
    OUT/backward.onnx    obs (N, obs_dim) -> embedding (N, z_dim): B of the normalised observation, for goal
                         prompts (z = B(goal)) and tracking (z_t = the projected sum of B over the next L states)
    OUT/fbcpr-onnx.json  sizes, input and output names, the control rate, the action mapping (per joint, how an
                         action becomes a PD target), and the stored reward prompts' z's by task name

`fbcpr export CKPT OUT --onnx` writes it; OUT is replaced atomically, as a checkpoint is.
"""
from __future__ import annotations

import contextlib
import copy
import io
import json
import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor, nn

from fbcpr.core.checkpoint import staging_dir, swap_into_place
from fbcpr.core.extras import require

if TYPE_CHECKING:
    from fbcpr.inference.bfm import BFM
    from fbcpr.methods.fb_cpr.model import FBCPRModel

ACTOR_FILE, BACKWARD_FILE, META_FILE = "actor.onnx", "backward.onnx", "fbcpr-onnx.json"
#: Version of the JSON's layout, for apps that read it.
FORMAT = 1
#: What an action means on each joint (`humanoid_env.actions.ActionMap.to_ctrl`), in words for apps.
TARGET_RULE = "target_rad = center + action * (up if action >= 0 else down), action clipped to [-1, 1]"


class ActorGraph(nn.Module):
    """obs, z -> the mean action: normalise obs, project z, the actor's tanh mean (`BFM.act` with mean=True)."""

    def __init__(self, model: FBCPRModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, obs: Tensor, z: Tensor) -> Tensor:
        return self.model.actor_mean(self.model.normalize(obs), self.model.project_z(z))


class BackwardGraph(nn.Module):
    """obs -> B(normalised obs), on the sqrt(z_dim) sphere (`BFM.backward`)."""

    def __init__(self, model: FBCPRModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, obs: Tensor) -> Tensor:
        return self.model.backward_map(self.model.normalize(obs))


def export_onnx(bfm: BFM, out: str | Path) -> Path:
    """Write actor.onnx, backward.onnx and fbcpr-onnx.json into `out` (a new folder, an empty one or an earlier
    ONNX export, replaced atomically); returns its path."""
    require("onnx", "onnx", "ONNX export")
    require("onnxscript", "onnx", "ONNX export")
    path = Path(out)
    tmp = staging_dir(path, META_FILE)
    model = bfm.model if bfm.device.type == "cpu" else copy.deepcopy(bfm.model).cpu()  # the BFM stays where it is
    batch = torch.export.Dim("batch")
    obs, z = torch.zeros(2, bfm.obs_dim), torch.ones(2, bfm.z_dim)
    _export(ActorGraph(model), (obs, z), tmp / ACTOR_FILE, ["obs", "z"], ["action"],
            {"obs": {0: batch}, "z": {0: batch}})
    _export(BackwardGraph(model), (obs,), tmp / BACKWARD_FILE, ["obs"], ["embedding"], {"obs": {0: batch}})
    (tmp / META_FILE).write_text(json.dumps(onnx_metadata(bfm), indent=1) + "\n")
    swap_into_place(tmp, path, META_FILE)
    return path


def _export(module: nn.Module, args: tuple[Tensor, ...], file: Path, inputs: list[str], outputs: list[str],
            dynamic: dict[str, dict[int, Any]]) -> None:
    """One graph in one file (weights inside), with a free batch size; the exporter's chatter is kept quiet."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), torch.inference_mode(False):
            warnings.simplefilter("ignore")
            torch.onnx.export(module.eval(), args, str(file), input_names=inputs, output_names=outputs,
                              dynamic_shapes=dynamic, external_data=False)
    finally:
        logger.setLevel(level)


def onnx_metadata(bfm: BFM) -> dict[str, Any]:
    """What an app needs beside the graphs: sizes and names, the control rate, the action mapping, stored prompts."""
    from humanoid_env.model import CONTROL_HZ

    prompts = bfm.reward_prompts
    return {
        "format": FORMAT,
        "source": bfm.source,
        "env": bfm.env_name,
        "obs_dim": bfm.obs_dim, "action_dim": bfm.action_dim, "z_dim": bfm.z_dim,
        "sequence_length": bfm.sequence_length,
        "control_hz": CONTROL_HZ,
        "actor": {"file": ACTOR_FILE, "inputs": {"obs": ["N", bfm.obs_dim], "z": ["N", bfm.z_dim]},
                  "outputs": {"action": ["N", bfm.action_dim]}},
        "backward": {"file": BACKWARD_FILE, "inputs": {"obs": ["N", bfm.obs_dim]},
                     "outputs": {"embedding": ["N", bfm.z_dim]}},
        "action_mapping": action_mapping(bfm),
        "prompts": {} if prompts is None else {task: _floats(z) for task, z in sorted(prompts.z.items())},
        "refined_prompts": [] if prompts is None else sorted(prompts.refined),
    }


def action_mapping(bfm: BFM) -> dict[str, Any]:
    """The mapping's name and, for the humanoid, its per-joint arrays (`humanoid_env.actions.ActionMap`)."""
    out: dict[str, Any] = {"name": bfm.action_mapping}
    if bfm.env_name == "humanoid":
        from humanoid_env.actions import ActionMap
        from humanoid_env.model import JOINT_NAMES, load_model

        amap = ActionMap(load_model(), bfm.action_mapping)
        out.update(rule=TARGET_RULE, joints=list(JOINT_NAMES), center=_floats(amap.center), up=_floats(amap.up),
                   down=_floats(amap.down))
    return out


def _floats(x: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(x, dtype=np.float64).ravel()]
