"""Reward-prompt time (relabel 100k buffer samples + weighted regression) and act() latency at batch 1, for a
paper-S sized model on CPU, each next to a plain torch reference measured in the same run.

    python benchmarks/prompt_speed.py [--n 100000] [--preset paper-S] [--threads 0] [--act-calls 2000]
        [--checkpoint pretrained --checkpoint RUN/checkpoints/step_...]

`--checkpoint` also times a saved model from disk to its first reward prompt: loading, B over its whole
reward sample and, for a sample stored as states only (`fbcpr export`), rebuilding the observations first; or, for
a prompt stored at export (`--store-prompts`), loading alone.

Targets (issue 6): a reward prompt in <= 2 s (the paper reports about 10 s for this step), act() <= 2 ms.
The model is untrained (timing does not depend on the weights); the reward-inference buffer holds real
humanoid states (goal poses and frames of the built-in clips, with their qpos/qvel).
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import torch

from fbcpr.core.config import config_from_dict
from fbcpr.inference.bfm import BFM
from fbcpr.methods.fb_cpr.model import FBCPRModel

TASKS = ["move-ego-0-2", "crouch-0", "raisearms-h-l", "sitonground", "move-ego-0-2*raisearms-h-h"]


def make_buffer(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """n states drawn from goal poses and built-in clip frames, with consistent next_obs, qpos and qvel."""
    from humanoid_env.tasks.goals import goal_names, goal_obs, goal_qpos
    from motions.synthetic import default_clips

    clips = default_clips()
    goals = goal_names()
    obs = np.concatenate([np.stack([goal_obs(g) for g in goals])] + [c.obs for c in clips]).astype(np.float32)
    qpos = np.concatenate([np.stack([goal_qpos(g) for g in goals])] + [c.qpos for c in clips])
    qvel = np.concatenate([np.zeros((len(goals), 75))] + [c.qvel for c in clips])
    idx = rng.integers(0, len(obs), n)
    return {"next_obs": obs[idx], "qpos": qpos[idx].astype(np.float32), "qvel": qvel[idx].astype(np.float32)}


def timed(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def latency(fn, calls: int) -> float:
    """Median seconds per call after a warm-up."""
    for _ in range(50):
        fn()
    times = []
    for _ in range(calls):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=100_000)
    parser.add_argument("--preset", default="paper-S")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--act-calls", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--checkpoint", action="append", default=[], help="also time load + first reward prompt")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = config_from_dict({"model": {"preset": args.preset, "obs_dim": 358, "action_dim": 69}})
    model = FBCPRModel(cfg.model)
    buf = make_buffer(args.n, np.random.default_rng(0))
    model.obs_normalizer.update(torch.as_tensor(buf["next_obs"][:10_000]))
    bfm = BFM(model, cfg, reward_buffer=buf)
    params = sum(p.numel() for p in model.actor.parameters())
    print(f"model {args.preset}: z_dim {cfg.model.z_dim}, actor {params / 1e6:.2f}M params; buffer {args.n} states; "
          f"torch {torch.__version__}, {torch.get_num_threads()} threads, python {platform.python_version()}, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")

    # --- reward prompt ---------------------------------------------------------------------------------
    x = torch.as_tensor(buf["next_obs"])
    w = torch.randn(358, cfg.model.z_dim)
    ref = timed(lambda: x @ w, args.repeats)
    print(f"\nreward prompt over {args.n} samples (best of {args.repeats}); target <= 2 s, paper ~10 s")
    print(f"  {'reference: one (n,358)@(358,d) matmul':46s} {ref * 1e3:8.1f} ms")
    for task in TASKS:
        # cold: a freshly loaded model computes B over the buffer, relabels and regresses
        cold = timed(lambda: BFM(model, cfg, reward_buffer=buf).prompt.reward(task), args.repeats)
        bfm.prompt.reward(task)
        warm = timed(lambda: bfm.prompt.reward(task), args.repeats)  # B cached by the model: relabel + regression
        print(f"  {task:46s} {cold * 1e3:8.1f} ms cold, {warm * 1e3:7.1f} ms with B cached  "
              f"({cold / ref:5.1f}x the matmul)")

    for ckpt in args.checkpoint:
        loaded: list[BFM] = []

        def load_and_prompt() -> None:
            loaded.append(BFM.load(ckpt))
            loaded[-1].prompt.reward(TASKS[0])

        first = timed(load_and_prompt, args.repeats)
        stored = loaded[-1].reward_prompts
        source = (f"stored at export from {stored.states} states, none read" if stored and TASKS[0] in stored.z
                  else f"{len(loaded[-1].reward_buffer['qpos'])} states")  # the last timed load's, already read
        print(f"  {f'{ckpt}: load + first {TASKS[0]}':46s} {first * 1e3:8.1f} ms ({source}, "
              f"{first / ref:5.1f}x the matmul)")

    # --- act latency ------------------------------------------------------------------------------------
    obs = buf["next_obs"][0]
    z = bfm.prompt.goal(obs)
    lin = torch.nn.Linear(cfg.model.hidden_dim, cfg.model.hidden_dim)
    h = torch.randn(1, cfg.model.hidden_dim)

    def ref_layer() -> None:
        with torch.inference_mode():
            lin(h)

    t_ref = latency(ref_layer, args.act_calls)
    t_np = latency(lambda: bfm.act(obs, z), args.act_calls)
    obs_t, z_t = torch.as_tensor(obs), torch.as_tensor(z)
    t_torch = latency(lambda: bfm.act(obs_t, z_t), args.act_calls)
    print(f"\nact() at batch 1, median of {args.act_calls} calls; target <= 2 ms")
    ref_name = f"reference: one Linear({cfg.model.hidden_dim},{cfg.model.hidden_dim}) forward"
    print(f"  {ref_name:46s} {t_ref * 1e3:8.3f} ms")
    print(f"  {'bfm.act(numpy (358,), numpy z)':46s} {t_np * 1e3:8.3f} ms  ({t_np / t_ref:5.1f}x the layer)")
    print(f"  {'bfm.act(torch (358,), torch z)':46s} {t_torch * 1e3:8.3f} ms  ({t_torch / t_ref:5.1f}x the layer)")


if __name__ == "__main__":
    main()
