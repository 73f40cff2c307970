"""Bring a checkpoint back from a GPU run, whose $OUT returns at most 8 files of 16 MiB, 64 MiB in all.

A paper-S model is 73.5 MiB in float32, more than one call returns. So the newest checkpoint of a run travels as
its network parameters in float16 (36.8 MiB; relative rounding <= 2^-11, the normaliser's statistics and any
tensor float16 cannot hold stay float32), its config, and a float16 subsample of its reward buffer sized to fit,
in one tar split into parts. The reward states travel without their observations (qpos and qvel, 302 bytes a
state instead of 1,018), as `fbcpr export --states-only` stores them: loading rebuilds the observations. `unpack`
turns them back into an ordinary (float32 weights) inference checkpoint:

    python lab/gpu/pack.py pack RUN_DIR OUT_DIR [--parts 6]    # on the device
    python lab/gpu/pack.py unpack FILES_DIR DEST_DIR           # here: DEST_DIR/step_XXXXXXXXXX
"""
from __future__ import annotations

import argparse
import io
import os
import tarfile
from pathlib import Path

PART_BYTES = 16 * 2**20 - 2**16  # under the 16 MiB a returned file may have
TOTAL_BYTES = 63 * 2**20         # under the 64 MiB a call returns: 1 MiB left for metrics.csv and status.txt
SLACK_BYTES = 2**19              # tar and safetensors headers, config.yaml
PART = ".tar.part"               # parts are named step_XXXXXXXXXX.tar.part<i>-of-<n>
WEIGHTS, REWARDS, CONFIG = "weights.safetensors", "reward_buffer.safetensors", "config.yaml"


def pack(run_dir: Path, out_dir: Path, parts: int) -> list[Path]:
    """Write the run's newest checkpoint as at most `parts` files into out_dir (replacing earlier parts)."""
    import torch
    from safetensors.torch import save

    from fbcpr.inference.bfm import BFM, resolve_checkpoint
    from fbcpr.core.checkpoint import CONFIG_FILE, MAX_REBUILT_STATES, STATE_KEYS

    ckpt = resolve_checkpoint(run_dir)
    bfm = BFM.load(ckpt)
    params = {name for name, _ in bfm.model.named_parameters()}
    weights = {}
    for name, t in bfm.model.state_dict().items():
        half = t.half() if name in params and t.dtype == torch.float32 else t
        weights[name] = half if torch.isfinite(half).all() else t
    room = min(parts * PART_BYTES, TOTAL_BYTES) - SLACK_BYTES - sum(t.numel() * t.element_size() for t in weights.values())
    buf = bfm.reward_buffer
    keep = None if buf is None else min(len(buf["next_obs"]), MAX_REBUILT_STATES,
                                        room // (2 * sum(buf[k].shape[1] for k in STATE_KEYS)))
    if room < 0 or keep == 0:
        raise SystemExit(f"pack: {ckpt} does not fit in {parts} parts of {PART_BYTES} bytes")
    files = {WEIGHTS: save(weights), CONFIG: (ckpt / CONFIG_FILE).read_bytes()}
    if buf is not None:
        sample = bfm.reward_samples(keep, seed=0)[0]  # as `fbcpr export --reward-samples` draws them
        files[REWARDS] = save({k: torch.as_tensor(sample[k]).half() for k in STATE_KEYS})
    blob = io.BytesIO()
    with tarfile.open(fileobj=blob, mode="w") as tar:
        for fname, data in files.items():
            info = tarfile.TarInfo(f"{ckpt.name}/{fname}")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    data = blob.getvalue()
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob(f"*{PART}*"):
        old.unlink()
    n = -(-len(data) // PART_BYTES)
    written = []
    for i in range(n):
        path = out_dir / f"{ckpt.name}{PART}{i}-of-{n}"
        tmp = out_dir / f".{path.name}.tmp"
        tmp.write_bytes(data[i * PART_BYTES:(i + 1) * PART_BYTES])
        os.replace(tmp, path)  # a GPU run cut short leaves whole parts only; unpack checks that all n are there
        written.append(path)
    n_buf = "no reward buffer" if buf is None else f"{keep} of {len(buf['next_obs'])} reward states"
    print(f"packed {ckpt} (float16 weights, {n_buf}): {len(data) / 2**20:.1f} MiB in {n} part(s) in {out_dir}")
    return written


def unpack(files_dir: Path, dest: Path) -> Path:
    """Join the parts found in files_dir into the inference checkpoint dest/<checkpoint name>; returns its path."""
    import torch
    import yaml
    from safetensors.torch import load

    from fbcpr import BFM
    from fbcpr.core.checkpoint import load_state_strict, save_checkpoint
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    found = {}
    for p in files_dir.glob(f"[!.]*{PART}*-of-*"):  # not the .tmp of a part cut short
        name, tail = p.name.rsplit(PART, 1)
        i, n = tail.split("-of-")
        found[(name, int(n), int(i))] = p
    sets = sorted({(name, n) for name, n, _ in found})
    if len(sets) != 1:
        raise SystemExit(f"unpack: expected the parts of one checkpoint in {files_dir}, found {sets or 'none'}")
    (name, n), = sets
    missing = [i for i in range(n) if (name, n, i) not in found]
    if missing:
        raise SystemExit(f"unpack: {name} misses part(s) {missing} of {n} in {files_dir}")
    with tarfile.open(fileobj=io.BytesIO(b"".join(found[(name, n, i)].read_bytes() for i in range(n)))) as tar:
        files = {m.name.split("/", 1)[1]: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}
    cfg = config_from_dict(yaml.safe_load(files[CONFIG]))
    model = FBCPRModel(cfg.model)
    weights = {k: v.float() if v.dtype == torch.float16 else v for k, v in load(files[WEIGHTS]).items()}
    load_state_strict(model, weights, f"{name}/{WEIGHTS}")
    rewards = load(files[REWARDS]) if REWARDS in files else None
    path = save_checkpoint(dest / name, model, cfg, reward_buffer=rewards, reward_dtype=torch.float16,
                           reward_obs=False)
    bfm = BFM.load(path)
    states = len(bfm.reward_buffer["next_obs"]) if bfm.reward_buffer is not None else 0
    print(f"unpacked {path}: z_dim {bfm.z_dim}, action mapping {bfm.action_mapping}, {states} reward states")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("pack", help="on the device: newest checkpoint of RUN_DIR -> parts in OUT_DIR")
    p.add_argument("run_dir", type=Path)
    p.add_argument("out_dir", type=Path)
    p.add_argument("--parts", type=int, default=6, help="at most this many files (8 minus the other returned files)")
    u = sub.add_parser("unpack", help="here: parts in FILES_DIR -> DEST_DIR/<checkpoint name>")
    u.add_argument("files_dir", type=Path)
    u.add_argument("dest", type=Path)
    args = ap.parse_args()
    if args.cmd == "pack":
        pack(args.run_dir, args.out_dir, args.parts)
    else:
        unpack(args.files_dir, args.dest)


if __name__ == "__main__":
    main()
