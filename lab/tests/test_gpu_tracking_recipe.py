"""The GPU window's tracking command (lab/configs/gpu-tracking-held.yaml, INIT_FROM=pretrained, CLIP_PACK) rehearsed
on the CPU at tiny sizes: its clips come back from a pack where the config reads them, and the shipped model
warm-starts that recipe, trains a few updates with B frozen and writes a checkpoint. A GPU window is short and
rare: a recipe that cannot load its model should fail here, not there."""
import dataclasses
import subprocess
import sys
from pathlib import Path

import torch

from fbcpr import BFM
from fbcpr.core.checkpoint import latest_checkpoint, load_checkpoint
from fbcpr.core.config import load_config
from fbcpr.train.trainer import Trainer
from motions.clip import save_clip
from motions.synthetic import squat, walk

ROOT = Path(__file__).resolve().parents[2]


def test_the_gpu_tracking_recipe_warm_starts_the_shipped_model_on_clips_from_a_pack(tmp_path, monkeypatch):
    monkeypatch.setenv("FBCPR_DATA", str(tmp_path / "data"))
    src = tmp_path / "takes"
    # one take of each CMU form the recipe leaves free (agent.anchor_free), and a DeepMimic-like clip it holds
    for name in ("asfamc_walk", "bvh_walk", "bvh-daz_walk", "expmap_walk", "deepmimic_squat"):
        clip = squat(1.0) if name.endswith("squat") else walk(1.0)
        save_clip(dataclasses.replace(clip, name=name), src / f"{name}.npz")
    pack = tmp_path / "data" / "clips" / "tracking-train.pack.npz"   # where build_carry.sh puts it
    for args in (("pack", src, pack), ("unpack", pack, str(pack).removesuffix(".pack.npz"))):  # as gpu_window.sh does
        done = subprocess.run([sys.executable, "lab/gpu/clip_pack.py", *map(str, args)], cwd=ROOT, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, done.stderr

    cfg = load_config(ROOT / "lab" / "configs" / "gpu-tracking-held.yaml")
    assert cfg.env.motions == str(tmp_path / "data" / "clips" / "tracking-train")
    t = cfg.train
    t.device, t.num_envs, t.warmup_steps, t.rollout_steps, t.updates_per_rollout = "cpu", 2, 32, 16, 2
    t.total_env_steps, t.buffer_capacity, t.buffer_memmap_mb, t.reward_buffer_size = 64, 2000, 0, 64
    t.priority_every, t.checkpoint_every, t.torch_threads = 0, 0, 1
    cfg.agent.batch_size = 16
    trainer = Trainer(cfg, tmp_path / "run", progress=False, init_from="pretrained")
    try:
        summary = trainer.run()
    finally:
        trainer.close()
    assert summary["env_steps"] == 64 and summary["updates"] > 0
    shipped = BFM.pretrained().model.state_dict()
    after = load_checkpoint(latest_checkpoint(tmp_path / "run" / "checkpoints")).model.state_dict()
    backward = [k for k in shipped if k.startswith(("backward_map", "obs_normalizer"))]
    assert backward and all(torch.equal(after[k], shipped[k]) for k in backward)  # B and the normaliser held
    assert any(not torch.equal(after[k], shipped[k]) for k in shipped if k.startswith("actor"))  # the actor learnt
