"""Bring a checkpoint back from a GPU lease, whose $OUT returns at most 8 files of at most 16 MiB each.

A paper-S model alone is 73.5 MiB, so the newest checkpoint of a run is exported as an inference checkpoint
(weights, config, manifest and a float16 reward subsample sized to fit) and returned as one tar in parts:

    python benchmarks/gpu_lease/pack.py pack RUN_DIR OUT_DIR [--parts 6]    # on the device
    python benchmarks/gpu_lease/pack.py unpack FILES_DIR DEST_DIR           # here: DEST_DIR/step_XXXXXXXXXX
"""
from __future__ import annotations

import argparse
import io
import os
import shutil
import tarfile
from pathlib import Path

PART_BYTES = 16 * 2**20 - 2**16  # under the 16 MiB a returned file may have
SLACK_BYTES = 2**20              # tar headers, config.yaml, manifest.json and the safetensors headers
PART = ".tar.part"  # parts are named step_XXXXXXXXXX.tar.part<i>-of-<n>


def pack(run_dir: Path, out_dir: Path, parts: int) -> list[Path]:
    """Export the run's newest checkpoint into at most `parts` files in out_dir (replacing earlier parts)."""
    from fbcpr.bfm import BFM, resolve_checkpoint
    from fbcpr.checkpoint import MODEL_FILE

    ckpt = resolve_checkpoint(run_dir)
    bfm = BFM.load(ckpt)
    buf = bfm.reward_buffer
    room = parts * PART_BYTES - SLACK_BYTES - (ckpt / MODEL_FILE).stat().st_size
    keep = None if buf is None else min(len(buf["next_obs"]), room // (2 * sum(v.shape[1] for v in buf.values())))
    if room < 0 or keep == 0:
        raise SystemExit(f"pack: {ckpt} does not fit in {parts} parts of {PART_BYTES} bytes")
    shutil.rmtree(run_dir / ".pack", ignore_errors=True)
    stage = bfm.save(run_dir / ".pack" / ckpt.name, reward_samples=keep, half=True)
    blob = io.BytesIO()
    with tarfile.open(fileobj=blob, mode="w") as tar:
        tar.add(stage, arcname=ckpt.name)
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
        os.replace(tmp, path)  # a lease cut short leaves whole parts only; unpack checks that all n are there
        written.append(path)
    n_buf = "no reward buffer" if buf is None else f"{keep} of {len(buf['next_obs'])} reward states (float16)"
    print(f"packed {ckpt} ({n_buf}): {len(data) / 2**20:.1f} MiB in {len(written)} part(s) in {out_dir}")
    return written


def unpack(files_dir: Path, dest: Path) -> Path:
    """Join the parts found in files_dir and extract the checkpoint folder into dest; returns its path."""
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
    parts = [found[(name, n, i)] for i in range(n)]
    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(b"".join(p.read_bytes() for p in parts))) as tar:
        tar.extractall(dest, filter="data")
    path = dest / name
    from fbcpr.bfm import BFM

    bfm = BFM.load(path)  # verifies every file against its manifest checksums
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
