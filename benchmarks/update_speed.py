"""Milliseconds per full FB-CPR update (all five networks, targets, Polyak) at several sizes.

    python benchmarks/update_speed.py [--threads 2] [--sizes tiny small paper-S] [--gpu] [--compile] [--graph]

Humanoid dimensions (obs 358, action 69). Each row shows the measured update next to a reference taken in
the same run: square float32 matmuls of the same total FLOPs (counted with torch's FlopCounterMode on one
update), i.e. what the update would cost if all its math ran at dense float32 GEMM speed, and a
straightforward implementation of the same losses (one network at a time, no shared passes). `--bf16` adds
rows for the optional bf16 autocast switch (`agent.bf16`; float32 master weights and optimiser); `--near` rows for
the NEAR regulariser (`agent.regulariser: near`, its default 3 x 512 energy) in the discriminator's place. The last
column counts the kernels of one update on the CPU: the non-view aten operators of its forward and backward passes and
its optimiser steps (`fbcpr.nn.kernel_count`); for a `--compile` row, the kernels inductor generated for the CPU plus
the operators called outside them (`count_compiled_update`).
`--graph` adds GPU rows for the update captured in a CUDA graph (`agent.cuda_graph`), and first checks, per size,
that the graphed update trains as the eager one does: twins from the same seed, fed the same batches, with
exploration actions drawn between updates, are compared after every update.
"""
from __future__ import annotations

import argparse
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from fbcpr.core.config import config_from_dict
from fbcpr.methods.fb_cpr import losses
from fbcpr.methods.fb_cpr.agent import FBCPRAgent
from fbcpr.nn.cuda_graph import make_capturable
from fbcpr.nn.kernel_count import count_compiled_update, count_update_kernels
from fbcpr.nn.networks import project_sphere

SIZES = {"tiny": 256, "small": 256, "paper-S": 1024, "paper-M": 1024}
#: The graphed and eager twins agree when every difference stays below this, or below FLOOR_FACTOR times the
#: difference between two eager twins on the same device. On an H100 (2026-11-26) the eager twins agreed exactly
#: and the graphed one was 3.5e-4 off on the metrics, 5e-7 on the actions and 1.7e-7 on all weights (kernels picked
#: inside a capture round differently); a graph that replays stale inputs or the same random draws departs by far
#: more within a few updates.
AGREE = 1e-3
FLOOR_FACTOR = 10.0
OBS, ACT = 358, 69


def make(preset: str, device: str, compile_: bool, bf16: bool = False, regulariser: str = "discriminator",
         graph: bool = False, data_seed: int = 0) -> tuple[FBCPRAgent, dict, torch.Tensor]:
    n = SIZES[preset]
    cfg = config_from_dict({"model": {"preset": preset, "obs_dim": OBS, "action_dim": ACT},
                            "agent": {"batch_size": n, "compile": compile_, "bf16": bf16, "regulariser": regulariser,
                                      "cuda_graph": graph}})
    agent = FBCPRAgent(cfg.model, cfg.agent, device=device)
    return (agent, *draw(n, cfg.model.z_dim, data_seed))


def draw(n: int, z_dim: int, seed: int) -> tuple[dict, torch.Tensor]:
    """A replay batch of n random humanoid-sized transitions and n / 8 expert windows of 8 states."""
    g = torch.Generator().manual_seed(seed)
    batch = {"obs": torch.randn(n, OBS, generator=g), "action": torch.rand(n, ACT, generator=g) * 2 - 1,
             "next_obs": torch.randn(n, OBS, generator=g),
             "z": project_sphere(torch.randn(n, z_dim, generator=g)), "terminated": torch.zeros(n)}
    return batch, torch.randn(n // 8, 8, OBS, generator=g)


def straightforward_update(agent: FBCPRAgent, batch: dict, windows: torch.Tensor) -> None:
    """Reference: the same losses computed the textbook way, one network at a time, each loss with its own
    forward passes and its own backward (no shared passes, the actor loss backpropagates through F and Q's
    weights, per-parameter Polyak loop)."""
    m, cfg, t = agent.model, agent.cfg, agent.targets
    obs, act, nxt, z_buf = batch["obs"], batch["action"], batch["next_obs"], batch["z"]
    disc = cfg.discount * (1 - batch["terminated"])
    m.obs_normalizer.update(torch.cat([obs, windows.reshape(-1, obs.shape[1])]))
    s, s2, e = m.normalize(obs), m.normalize(nxt), m.normalize(windows)
    w, L, o = e.shape
    opt = agent.optimizers
    z_e = agent.encode_windows(e).repeat_interleave(L, 0)
    s_e = e.reshape(-1, o)
    loss = losses.discriminator_loss(m.discriminator.logits(s_e, z_e), m.discriminator.logits(s, z_buf))
    loss = loss + cfg.grad_penalty * losses.gradient_penalty(m.discriminator, s_e, z_e, s, z_buf, torch.rand(len(s)))
    opt["discriminator"].zero_grad()
    loss.backward()
    opt["discriminator"].step()
    with torch.no_grad():
        z = agent.relabel(z_buf, m.backward_map(s2), agent.encode_windows(e))
        a2 = m.actor_sample(s2, z)
        F2 = t["forward_map"](s2, a2, z)
        tM = losses.pessimistic(torch.einsum("mid,jd->mij", F2, t["backward_map"](s2)), cfg.fb_pessimism)
        tFz = losses.pessimistic((F2 * z).sum(-1), cfg.fz_pessimism)
    B2 = m.backward_map(s2)
    Fsa = m.forward_map(s, act, z)
    fz = losses.td_loss((Fsa * z).sum(-1), losses.implicit_reward(B2.detach(), z), tFz, disc)
    loss = (losses.fb_loss(torch.einsum("mid,jd->mij", Fsa, B2), tM, disc)
            + cfg.ortho_coef * losses.ortho_loss(m.backward_map(s2)) + cfg.fz_coef * fz)
    opt["forward_map"].zero_grad()
    opt["backward_map"].zero_grad()
    loss.backward()
    opt["forward_map"].step()
    opt["backward_map"].step()
    with torch.no_grad():
        r = m.discriminator.logits(s, z)
        tQ = losses.pessimistic(t["critic"](s2, m.actor_sample(s2, z), z)[..., 0], cfg.critic_pessimism)
    loss = losses.td_loss(m.critic(s, act, z)[..., 0], r, tQ, disc)
    opt["critic"].zero_grad()
    loss.backward()
    opt["critic"].step()
    a = m.actor_sample(s, z)
    loss = losses.actor_loss((m.forward_map(s, a, z) * z).sum(-1), m.critic(s, a, z)[..., 0], cfg.actor_reg_coef,
                             cfg.actor_pessimism)
    opt["actor"].zero_grad()
    loss.backward()
    opt["actor"].step()
    with torch.no_grad():
        for k in ("forward_map", "backward_map", "critic"):
            for pt, p in zip(t[k].parameters(), getattr(m, k).parameters()):
                pt.mul_(1 - cfg.tau).add_(cfg.tau * p)


def time_straightforward(agent: FBCPRAgent, batch: dict, windows: torch.Tensor, reps: int) -> float:
    for _ in range(2):
        straightforward_update(agent, batch, windows)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        straightforward_update(agent, batch, windows)
        best = min(best, time.perf_counter() - t)
    return best


def sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def time_update(agent: FBCPRAgent, batch: dict, windows: torch.Tensor, device: str, reps: int) -> float:
    batch = {k: v.to(device) for k, v in batch.items()}
    windows = windows.to(device)
    for _ in range(5):  # a graphed update runs 3 eager warm-up calls and captures on the 4th
        agent.update(batch, windows)
    sync(device)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        agent.update(batch, windows)
        sync(device)
        best = min(best, time.perf_counter() - t)
    return best


def twin_differences(a: FBCPRAgent, b: FBCPRAgent, preset: str, device: str,
                     updates: int) -> tuple[tuple[float, float, float], list[tuple[str, float]]]:
    """Two agents updated on the same batches (a new one each update), with exploration actions drawn from their
    generators between updates, as in training: the largest relative difference of the metrics over all updates, the
    largest difference of the actions, and the relative norm of the difference of all weights at the end; then, per
    update, the metric that differs most and by how much (rounding grows slowly from the first update on, a graph
    that replays the wrong thing jumps at its first replay)."""
    per_update: list[tuple[str, float]] = []
    action_diff = 0.0
    for step in range(updates):
        batch, windows = draw(SIZES[preset], a.z_dim, step)
        m_a, m_b = a.update(batch, windows), b.update(batch, windows)
        per_update.append(max(((k, abs(m_a[k] - m_b[k]) / max(abs(m_a[k]), 1e-6)) for k in m_a),
                              key=lambda kv: kv[1]))
        obs, z = batch["obs"][:64].to(device), batch["z"][:64].to(device)
        action_diff = max(action_diff, float((a.act(obs, z) - b.act(obs, z)).abs().max()))
    with torch.no_grad():
        p = torch.cat([x.flatten() for x in a.model.parameters()])
        q = torch.cat([x.flatten() for x in b.model.parameters()])
        weights = float((p - q).norm() / p.norm().clamp_min(1e-12))
    return (max(d for _, d in per_update), action_diff, weights), per_update


def graph_agreement(preset: str, device: str = "cuda", updates: int = 12) -> str:
    """A graphed agent against an eager one from the same seed, judged against two eager twins from that seed (the
    device's own nondeterminism), with the graphed agent's largest metric difference per update, and against an eager
    agent with the graph's capturable Adam (what the capture alone changes). (Off CUDA every agent runs eagerly, so
    every difference is 0.)"""
    eager, graphed = make(preset, device, False)[0], make(preset, device, False, graph=True)[0]
    got, per_update = twin_differences(eager, graphed, preset, device, updates)
    floor = twin_differences(make(preset, device, False)[0], make(preset, device, False)[0], preset, device,
                             updates)[0]
    # the graph's Adam steps on the device (`capturable`), whose bias correction rounds in float32: an eager agent
    # with that Adam tells the capture's own difference from the optimiser's
    capturable = make(preset, device, False)[0]
    if device.startswith("cuda"):
        for optimizer in capturable.optimizers.values():
            make_capturable(optimizer)
    adam = twin_differences(capturable, make(preset, device, False, graph=True)[0], preset, device, updates)[0]
    step = graphed._step
    state = ("eager (not CUDA)" if not graphed.graphed else "captured" if step.captured
             else f"NOT captured: {step.failure}")
    agree = all(g < max(AGREE, FLOOR_FACTOR * f) for g, f in zip(got, floor))
    growth = ", ".join(f"{i + 1}: {k} {d:.1e}" for i, (k, d) in enumerate(per_update))
    return (f"{preset}: {state}; {'agree' if agree else 'DIFFER'}; after {updates} updates, graphed vs eager "
            f"(eager twins): metrics max rel diff {got[0]:.2e} ({floor[0]:.2e}), actions max abs diff {got[1]:.2e} "
            f"({floor[1]:.2e}), weights rel norm diff {got[2]:.2e} ({floor[2]:.2e}); graphed vs eager with the "
            f"graph's capturable Adam: {adam[0]:.2e}, {adam[1]:.2e}, {adam[2]:.2e}; per update, the metric that "
            f"differs most: {growth}")


def count_flops(preset: str) -> float:
    agent, batch, windows = make(preset, "cpu", False)
    with FlopCounterMode(display=False) as fc:
        agent.update(batch, windows)
    return float(fc.get_total_flops())


def matmul_reference(flops: float, device: str, reps: int) -> float:
    """Seconds for square 1024 float32 matmuls totalling `flops`."""
    k = 1024
    a, b = torch.randn(k, k, device=device), torch.randn(k, k, device=device)
    count = max(1, round(flops / (2 * k ** 3)))
    for _ in range(3):
        a @ b
    sync(device)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        for _ in range(count):
            a @ b
        sync(device)
        best = min(best, time.perf_counter() - t)
    return best * flops / (count * 2 * k ** 3)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sizes", nargs="+", default=["tiny", "small", "paper-S"])
    ap.add_argument("--reps", type=int, help="timed updates per row (default: 20 tiny, 10 small, 3 larger on CPU; "
                    "20 on GPU)")
    ap.add_argument("--gpu", action="store_true", help="also time on CUDA")
    ap.add_argument("--compile", action="store_true", help="also time torch.compile of the loss computation "
                    "(agent.compile; after the eager rows: compiling takes minutes), on the GPU with --gpu, else on "
                    "the CPU")
    ap.add_argument("--bf16", action="store_true", help="also time the bf16-autocast switch (agent.bf16)")
    ap.add_argument("--near", action="store_true", help="also time the NEAR regulariser (agent.regulariser: near)")
    ap.add_argument("--graph", action="store_true", help="also check and time the update captured in a CUDA graph "
                    "(agent.cuda_graph; GPU rows)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    devices = ["cpu"] + (["cuda"] if args.gpu and torch.cuda.is_available() else [])
    gpu_name = f", {torch.cuda.get_device_name()}" if "cuda" in devices else ""
    print(f"torch {torch.__version__}, {args.threads} CPU threads{gpu_name}")
    print(f"{'size':8s} {'device':14s} {'batch':>5s} {'GFLOP':>7s} {'ms/update':>10s} {'matmul ref ms':>14s} "
          f"{'ratio':>6s} {'straightforward ms':>19s} {'kernels':>8s}")
    if args.graph and "cuda" in devices:
        for preset in args.sizes:
            print("agreement", graph_agreement(preset), flush=True)
    for preset in args.sizes:
        flops = count_flops(preset)
        for dev in devices:
            reps = args.reps or ({"tiny": 20, "small": 10}.get(preset, 3) if dev == "cpu" else 20)
            ref = matmul_reference(flops, dev, 3)
            naive = time_straightforward(*make(preset, "cpu", False), reps) * 1e3 if dev == "cpu" else float("nan")
            eager = [(False, False, "discriminator")] + [(True, False, "discriminator")] * args.bf16
            on_this_device = dev != "cpu" or not args.gpu  # compiled rows on the GPU with --gpu, else on the CPU
            compiled = [(bf16, True, reg) for bf16, _, reg in eager] if args.compile and on_this_device else []
            variants = [(bf16, comp, reg, False) for bf16, comp, reg in
                        eager + [(False, False, "near")] * args.near + compiled]
            if args.graph and dev != "cpu":
                variants += [(bf16, False, "discriminator", True) for bf16, _, _ in eager]
            for bf16, compile_, regulariser, graph in variants:
                # counted on the CPU: a graph replays the eager update's kernels; a compiled update is counted from
                # the profiler, with the kernels inductor generates for the CPU (before the timed agent compiles, which
                # then reuses the same code)
                kernels = str(count_compiled_update(*make(preset, "cpu", True, bf16, regulariser)).kernels if compile_
                              else count_update_kernels(*make(preset, "cpu", False, bf16, regulariser)))
                agent, batch, windows = make(preset, dev, compile_, bf16, regulariser, graph)
                t = time_update(agent, batch, windows, dev, reps)
                name = (dev + ("+bf16" if bf16 else "") + ("+near" if regulariser == "near" else "")
                        + ("+comp" if compile_ else "") + ("+graph" if graph else ""))
                print(f"{preset:8s} {name:14s} {SIZES[preset]:5d} {flops / 1e9:7.1f} {t * 1e3:10.1f} {ref * 1e3:14.1f} "
                      f"{t / ref:6.2f} {naive:19.1f} {kernels:>8s}", flush=True)


if __name__ == "__main__":
    main()
