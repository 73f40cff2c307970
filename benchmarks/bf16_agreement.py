"""How far the bf16 update's gradients are from float32's, next to how far two float32 batches' gradients are.

    python benchmarks/bf16_agreement.py fbcpr/configs/cpu.yaml --init-from pretrained --steps 4096 --batches 8

A warm-started run of CONFIG collects STEPS env steps with the loaded policy (no update), and on each of BATCHES
replay batches the update's losses and gradients are computed twice, in float32 and under `agent.bf16`
autocast, from the same weights, normaliser and random draws. Per optimised network it prints the cosine
between the two gradients and the relative size of their difference, and per loss the relative difference.
The reference, measured in the same run, is float32 against float32 on the next batch: the noise of the
minibatch gradient that training follows anyway. bf16 errors well below it change the update less than the
choice of batch does; lab/log.md section 28 uses it before comparing learning.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import tempfile

import numpy as np
import torch

from fbcpr.core.config import load_config
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.train.trainer import Trainer


def gradients(agent: FBCPRAgent, batch: dict, windows: torch.Tensor, bf16: bool) -> tuple[dict, dict]:
    """(per optimised network: its flat gradient, per loss: its value) of one update's backward, without a step;
    the normaliser and the agent's random stream are put back, so two calls see the same draws."""
    held = {"normalizer": copy.deepcopy(agent.model.obs_normalizer.state_dict()),
            "generator": agent.generator.get_state()}
    agent.bf16 = bf16
    losses = agent.backward(batch, windows)
    agent.model.obs_normalizer.load_state_dict(held["normalizer"])
    agent.generator.set_state(held["generator"])
    grads = {}
    for name, opt in agent.optimizers.items():
        flat = [p.grad.reshape(-1) for g in opt.param_groups for p in g["params"] if p.grad is not None]
        grads[name] = torch.cat(flat).double() if flat else torch.zeros(1, dtype=torch.float64)
    return grads, {k: float(v.detach().float()) for k, v in losses.items()}


def compare(a: dict, b: dict) -> dict[str, tuple[float, float]]:
    """Per network: (cosine, |a - b| / |a|) of two gradient dicts."""
    out = {}
    for k in a:
        norm = float(a[k].norm())
        cos = float(torch.nn.functional.cosine_similarity(a[k], b[k], dim=0))
        out[k] = (cos, float((a[k] - b[k]).norm()) / norm if norm > 0 else float("nan"))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", help="a training config (its agent and env; its agent.bf16 is ignored)")
    ap.add_argument("--init-from", default="pretrained", help="weights to start from ('pretrained': the shipped model)")
    ap.add_argument("--steps", type=int, default=4096, help="env steps the loaded policy collects first")
    ap.add_argument("--batches", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load_config(args.config)
    if cfg.algorithm != "fb_cpr":
        raise SystemExit(f"{args.config}: algorithm {cfg.algorithm!r}; this probe compares FB-CPR's update only")
    cfg = dataclasses.replace(
        cfg, agent=dataclasses.replace(cfg.agent, bf16=False),
        train=dataclasses.replace(cfg.train, seed=args.seed, warmup_steps=10 ** 12, eval_every=0, eval_at_start=False,
                                  checkpoint_every=0, torch_threads=args.threads, total_env_steps=args.steps))
    with tempfile.TemporaryDirectory() as out:
        trainer = Trainer(cfg, out, init_from=args.init_from)  # its progress bar goes to stderr
        trainer.run()  # fills the replay buffer with the loaded policy's rollouts; no update before warm-up ends
        agent = trainer.agent
        draws = [trainer.learner.sample_batch() for _ in range(args.batches + 1)]  # as training draws them
        collected = len(trainer.buffer)
        trainer.close()
    fp32 = [gradients(agent, b, w, bf16=False) for b, w in draws]
    bf16 = [gradients(agent, b, w, bf16=True) for b, w in draws[:-1]]
    vs_bf16 = [compare(f[0], b[0]) for f, b in zip(fp32, bf16)]
    vs_batch = [compare(f[0], g[0]) for f, g in zip(fp32, fp32[1:])]
    print(f"{args.batches} batches of {cfg.agent.batch_size} from {collected:,} transitions of {args.init_from} "
          f"under {args.config}")
    print(f"{'network':<15} {'cos fp32-bf16':>14} {'rel. diff':>10} | {'cos next batch (ref)':>21} {'rel. diff':>10}")
    for k in vs_bf16[0]:
        cb = [r[k][0] for r in vs_bf16]
        db = [r[k][1] for r in vs_bf16]
        cr = [r[k][0] for r in vs_batch]
        dr = [r[k][1] for r in vs_batch]
        print(f"{k:<15} {np.mean(cb):>9.4f} (min {min(cb):.3f}) {np.mean(db):>6.3f} | "
              f"{np.mean(cr):>14.4f} (min {min(cr):.3f}) {np.mean(dr):>6.3f}")
    print(f"{'loss':<15} {'rel. diff fp32-bf16':>20} | {'rel. diff next batch (ref)':>27}")
    for k in bf16[0][1]:
        if all(f[1][k] == 0 for f in fp32):  # e.g. the actor anchor's gap at the weights it anchors to
            print(f"{k:<15} {'0 in float32':>20} |")
            continue
        rb = [abs(b[1][k] - f[1][k]) / abs(f[1][k]) for f, b in zip(fp32, bf16) if f[1][k]]
        rr = [abs(g[1][k] - f[1][k]) / abs(f[1][k]) for f, g in zip(fp32, fp32[1:]) if f[1][k]]
        print(f"{k:<15} {np.mean(rb):>20.2e} | {np.mean(rr):>27.2e}")


if __name__ == "__main__":
    main()
