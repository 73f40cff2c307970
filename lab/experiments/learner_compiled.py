"""The compiled learner (`agent.compile`) against the eager one: kernels per update, then times alternated (lab log 70).

    OMP_NUM_THREADS=1 python lab/experiments/learner_compiled.py SIZE UPDATES     # SIZE: small or paper-S

Kernels: the eager update by the dispatch counter, the compiled one by `count_compiled_update` (inductor's kernels by
their profiler markers, plus the operators called outside them), split into matmuls, generated kernels and the rest.
Times: one eager and one compiled agent from the same seed on the update benchmark's random humanoid batch, one
update each in turn, UPDATES times; medians.
"""
from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from update_speed import make  # noqa: E402

from fbcpr.nn.kernel_count import INDUCTOR_KERNEL, count_compiled_update, count_update_kernels  # noqa: E402


def main() -> None:
    preset, reps = sys.argv[1], int(sys.argv[2])
    torch.set_num_threads(1)
    start = time.time()
    compiled, batch, windows = make(preset, "cpu", True)
    count = count_compiled_update(compiled, batch, windows)
    generated = sum(n for name, n in count.ops.items() if INDUCTOR_KERNEL.match(name))
    matmuls = sum(count.ops[f"aten::{op}"] for op in ("bmm", "baddbmm", "mm", "addmm"))
    print(f"{preset} compiled kernels {count.kernels}: {matmuls} matmuls, {generated} generated, "
          f"{count.kernels - matmuls - generated} other ({time.time() - start:.0f} s with the compile)", flush=True)
    print(f"{preset} eager kernels {count_update_kernels(*make(preset, 'cpu', False))}", flush=True)
    eager, e_batch, e_windows = make(preset, "cpu", False)
    eager.update(e_batch, e_windows)
    times: dict[str, list[float]] = {"eager": [], "compiled": []}
    for _ in range(reps):
        for name, agent, b, w in (("eager", eager, e_batch, e_windows), ("compiled", compiled, batch, windows)):
            t = time.perf_counter()
            float(agent.update(b, w)["fb_loss"])
            times[name].append(time.perf_counter() - t)
    e, c = statistics.median(times["eager"]), statistics.median(times["compiled"])
    print(f"{preset} eager {e * 1e3:.1f} ms compiled {c * 1e3:.1f} ms compiled speed {e / c:.2f}x "
          f"load {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
