"""The learner's self-test on the device a run is about to train on: whether the update captured in a CUDA graph
trains as the eager update does, and whether the bf16 update follows float32's.

    python benchmarks/learner_selftest.py --device cuda [--sizes small paper-S] [--updates 12]

Prints one line per check and ends with `SELFTEST ok` or `SELFTEST FAILED: ...` (exit status 1).

- Graph twins (per size): an eager agent and a graphed one from the same seed, fed the same batches with
  exploration actions drawn between updates (`update_speed.twin_differences`), judged against two eager twins
  (the device's own nondeterminism). A third pair, an eager agent whose Adam is capturable like the graph's,
  against a graphed one, tells the capture's own difference from the optimiser's: the graph fails the test only
  when it departs from that twin too (a graph replaying stale inputs or the same random draws departs by far more
  within a few updates). The optimisers are fused, and a fused Adam keeps its step counters on the device whether
  capturable or not, so the eager and graphed updates should now round their bias corrections alike.
- bf16 (per size): one update's gradients on the same batch, weights and random draws in float32 and in bf16
  (`bf16_agreement.gradients`); every optimised network's cosine must reach MIN_COSINE. Then two twins, float32
  and bf16, trained on the same batches: how far their weights drift apart, as a fraction of how far float32's
  weights moved.

Off CUDA every agent runs eagerly, so the graph twins agree exactly: the CPU path checks the machinery.
"""
from __future__ import annotations

import argparse

import torch
from bf16_agreement import compare, gradients
from update_speed import AGREE, FLOOR_FACTOR, SIZES, draw, make, twin_differences

from fbcpr.methods.fb_cpr.agent import FBCPRAgent

#: Each optimised network's bf16 gradient must have at least this cosine with float32's on the same batch (the
#: shipped small model's networks measured 0.95-1.0, docs/benchmarks.md).
MIN_COSINE = 0.95


def _capturable_eager(preset: str, device: str) -> FBCPRAgent:
    """An eager agent whose Adam is the graph's (capturable), on a CUDA device."""
    agent = make(preset, device, False)[0]
    if device.startswith("cuda"):
        for optimizer in agent.optimizers.values():
            for group in optimizer.param_groups:
                group["capturable"] = True
    return agent


def graph_twins(preset: str, device: str, updates: int) -> tuple[list[str], str]:
    """(failures, a line) of the graphed update against the eager one at `preset`."""
    graphed = make(preset, device, False, graph=True)[0]
    got, per_update = twin_differences(make(preset, device, False)[0], graphed, preset, device, updates)
    floor = twin_differences(make(preset, device, False)[0], make(preset, device, False)[0], preset, device,
                             updates)[0]
    adam = twin_differences(_capturable_eager(preset, device), make(preset, device, False, graph=True)[0], preset,
                            device, updates)[0]
    bound = [max(AGREE, FLOOR_FACTOR * f) for f in floor]
    step = graphed._step
    state = ("eager (not CUDA)" if not graphed.graphed else "captured" if step.captured
             else f"NOT captured: {step.failure}")
    eager_ok = all(g < b for g, b in zip(got, bound))
    capture_ok = all(a < b for a, b in zip(adam, bound))
    line = (f"graph {preset}: {state}; after {updates} updates (metrics rel, actions abs, weights rel) graphed vs "
            f"eager {got[0]:.2e} {got[1]:.2e} {got[2]:.2e}, eager twins {floor[0]:.2e} {floor[1]:.2e} "
            f"{floor[2]:.2e}, graphed vs capturable-Adam eager {adam[0]:.2e} {adam[1]:.2e} {adam[2]:.2e}; "
            f"worst metric per update: " + ", ".join(f"{k} {d:.1e}" for k, d in per_update))
    failures = []
    if graphed.graphed and not step.captured:
        failures.append(f"graph {preset}: the update was not captured ({step.failure})")
    if not capture_ok:
        failures.append(f"graph {preset}: the graphed update departs from the eager one with the same Adam "
                        f"({adam[0]:.2e} {adam[1]:.2e} {adam[2]:.2e} against bounds "
                        f"{bound[0]:.1e} {bound[1]:.1e} {bound[2]:.1e})")
    elif not eager_ok:
        line += "; graphed vs eager differ, by the capturable Adam's rounding alone"
    return failures, line


def bf16_drift(preset: str, device: str, updates: int) -> float:
    """|w_bf16 - w_fp32| / |w_fp32 - w_0| over all model weights after `updates` updates of twins from one seed on
    the same batches: the bf16 run's departure as a fraction of float32's own movement."""
    fp32, bf16 = make(preset, device, False)[0], make(preset, device, False, bf16=True)[0]
    start = torch.cat([p.detach().flatten() for p in fp32.model.parameters()])
    for step in range(updates):
        batch, windows = draw(SIZES[preset], fp32.z_dim, 1000 + step)
        fp32.update(batch, windows)
        bf16.update(batch, windows)
    a = torch.cat([p.detach().flatten() for p in fp32.model.parameters()])
    b = torch.cat([p.detach().flatten() for p in bf16.model.parameters()])
    return float((a - b).norm() / (a - start).norm().clamp_min(1e-12))


def bf16_agreement(preset: str, device: str, updates: int) -> tuple[list[str], str]:
    """(failures, a line): per optimised network, the cosine of bf16's gradient with float32's on one batch (and of
    float32's on the next batch, the minibatch noise), then the weights' drift over `updates` updates."""
    agent = make(preset, device, False)[0]
    (b0, w0), (b1, w1) = draw(SIZES[preset], agent.z_dim, 0), draw(SIZES[preset], agent.z_dim, 1)
    fp32 = gradients(agent, b0, w0, bf16=False)[0]
    vs_bf16 = compare(fp32, gradients(agent, b0, w0, bf16=True)[0])
    vs_next = compare(fp32, gradients(agent, b1, w1, bf16=False)[0])
    drift = bf16_drift(preset, device, updates)
    line = (f"bf16 {preset}: gradient cosine with float32 (next batch's) "
            + ", ".join(f"{k} {vs_bf16[k][0]:.4f} ({vs_next[k][0]:.3f})" for k in vs_bf16)
            + f"; after {updates} updates the bf16 weights are {drift:.3f} of float32's movement away")
    failures = [f"bf16 {preset}: {k}'s gradient has cosine {c:.4f} with float32's (at least {MIN_COSINE})"
                for k, (c, _) in vs_bf16.items() if not c >= MIN_COSINE]
    return failures, line


def selftest(device: str, sizes: tuple[str, ...] = ("small", "paper-S"), updates: int = 12,
             show: bool = False) -> list[str]:
    """Every check at every size on `device`; the failures (empty: all passed). `show` prints each check's line."""
    failures: list[str] = []
    for preset in sizes:
        for check in (graph_twins, bf16_agreement):
            got, line = check(preset, device, updates)
            failures += got
            if show:
                print(line, flush=True)
    return failures


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--sizes", nargs="+", default=["small", "paper-S"], choices=sorted(SIZES))
    ap.add_argument("--updates", type=int, default=12)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    failures = selftest(args.device, tuple(args.sizes), args.updates, show=True)
    print("SELFTEST ok" if not failures else "SELFTEST FAILED: " + "; ".join(failures), flush=True)
    raise SystemExit(1 if failures else 0)


if __name__ == "__main__":
    main()
