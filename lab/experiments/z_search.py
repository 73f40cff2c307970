"""A missing skill or a missing prompt? For each behaviour family a model fails, search z directly by rollouts.

1. Screen a wide pool of z's, each rolled out once from a standing and once from a fall start, judged by every
   family's physical check (`fbcpr.eval.behaviours`): the reward prompt of every task, the goal prompt of every
   named pose, the ER_FB of every clip given (whole clip), tracking z's every few frames along each clip, and
   z's drawn uniformly on the training sphere.
2. For each failed family, the cross-entropy method (`fbcpr.inference.refine`) climbs the family's own measure
   (jump: pelvis apex gain, sit: low pelvis, ...) from the best screened z.
3. The best few z's are confirmed on fresh starts (seed + 100). A z passing there means the skill is in the
   policy and the prompt misses it; none passing means the skill is not learnt (within this search).

`--judge Z.npy ...` only judges saved z's (a prompt refined by `fbcpr prompt --refine --save-z`) beside each
family's prompt, on the same fresh starts.

    python lab/experiments/z_search.py pretrained --behaviours runs/beh_shipped/behaviours.json \\
        --motions data/clips/deepmimic data/clips/mixed --out runs/z_search.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from fbcpr import BFM
from fbcpr.eval import behaviours as B
from fbcpr.inference.refine import Search, cross_entropy, project

#: per family, the measure the search ranks by and its sign (larger is better after the sign); sit and crouch rank
#: by the share of the last second in the posture (a low pelvis alone ranks lying first)
MEASURE = {"stand": ("speed", -1), "walk": ("speed", 1), "run": ("speed", 1), "jump": ("apex_gain", 1),
           "sit": ("held", 1), "lie_face_up": ("chest_up", 1), "get_up": ("pelvis", 1), "crouch": ("held", 1),
           "hands_up": ("lower_wrist_over_head", 1), "spin": ("yaw_rate", 1)}


def pool(bfm: BFM, motions: list[Path], n_random: int, frames_per_clip: int, seed: int) -> dict[str, np.ndarray]:
    """Candidate z's by label."""
    from humanoid_env.tasks import GOALS, TASKS
    from motions.library import MotionLibrary

    out = {f"reward:{t}": bfm.prompt.reward(t) for t in TASKS}
    out |= {f"goal:{g}": bfm.prompt.goal(g) for g in GOALS}
    for folder in motions:
        for clip in MotionLibrary.load(folder).clips:
            out[f"imitate:{clip.name}"] = bfm.prompt.imitate(clip)
            track = bfm.prompt.track(clip)
            for i in np.linspace(0, len(track) - 1, frames_per_clip).round().astype(int):
                out[f"track:{clip.name}@{i}"] = track[i]
    rng = np.random.default_rng(seed)
    out |= {f"random:{i}": z for i, z in enumerate(project(rng.standard_normal((n_random, bfm.z_dim))))}
    return {k: np.asarray(v, np.float32) for k, v in out.items()}


def judge_all(bfm: BFM, zs: np.ndarray, starts: dict[str, tuple[np.ndarray, np.ndarray]], fams: list[B.Family],
              steps: int, threads: int | None = None) -> dict[str, dict[str, np.ndarray]]:
    """Per family: pass (K, E) and measure (K, E) of each z from the family's start, E episodes each; rolled out in
    groups of `B.CHUNK` envs so the recorded observations stay small."""
    from humanoid_env.observation import OBS_DIM

    episodes = len(starts["standing"][0])
    wanted = sorted({f.start for f in fams})
    out = {f.name: {"pass": np.zeros((len(zs), episodes)), "measure": np.zeros((len(zs), episodes))} for f in fams}
    per = max(1, B.CHUNK // episodes)
    for start in wanted:
        qpos, qvel = starts[start]
        for lo in range(0, len(zs), per):
            group = zs[lo:lo + per]
            batch = B.Batch(z=np.repeat(group, episodes, 0), qpos=np.tile(qpos, (len(group), 1)),
                            qvel=np.tile(qvel, (len(group), 1)))
            obs = np.empty((steps + 1, len(batch.z), OBS_DIM), np.float32)

            dead = np.zeros(len(batch.z), bool)

            def keep(t: int, envs: slice, o: np.ndarray, q: np.ndarray, diverged: np.ndarray,
                     obs: np.ndarray = obs, dead: np.ndarray = dead) -> None:
                obs[t + 1, envs] = o
                dead[envs] |= diverged

            B.run_batch(bfm, batch, steps, keep, num_threads=threads)
            trace = B.Trace(obs)
            for f in fams:
                if f.start != start or f.judge is None:
                    continue
                ok, measures = f.judge(trace)
                key, sign = MEASURE[f.name]
                out[f.name]["pass"][lo:lo + per] = (ok & ~dead).reshape(len(group), episodes)
                out[f.name]["measure"][lo:lo + per] = sign * measures[key].reshape(len(group), episodes)
    return out


def judge_saved(bfm: BFM, fams: list[B.Family], args: argparse.Namespace) -> None:
    """Each family's prompt and every saved z, on the same fresh starts; one row per (family, z)."""
    saved = {str(p): np.load(p, allow_pickle=False).astype(np.float32) for p in args.judge}
    fresh = B.start_states(args.confirm, args.seed + 100)
    report: dict[str, Any] = {}
    for f in fams:
        zs = {f"reward:{f.prompt}": bfm.prompt.reward(f.prompt), **saved}
        r = judge_all(bfm, np.stack(list(zs.values())), fresh, [f], args.steps, args.threads)[f.name]
        key, sign = MEASURE[f.name]
        report[f.name] = {lab: {"pass": float(r["pass"][i].mean()), key: float(sign * r["measure"][i].mean())}
                          for i, lab in enumerate(zs)}
        print(f"{f.name}: {json.dumps(report[f.name])}", flush=True)
    args.out.write_text(json.dumps(report, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--behaviours", type=Path, help="behaviours.json of the model: search its failed families")
    ap.add_argument("--families", nargs="*", help="search these families instead")
    ap.add_argument("--motions", type=Path, nargs="*", default=[])
    ap.add_argument("--random", type=int, default=192, help="z's drawn on the sphere")
    ap.add_argument("--frames", type=int, default=6, help="tracking z's per clip")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--generations", type=int, default=5)
    ap.add_argument("--population", type=int, default=16)
    ap.add_argument("--confirm", type=int, default=4, help="fresh episodes for each confirmed z")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, help="torch and MuJoCo threads (default: all cores); 1 beside a training")
    ap.add_argument("--judge", type=Path, nargs="*", help="only judge these saved z's (.npy, e.g. from `fbcpr prompt "
                    "--refine --save-z`) and each family's prompt on --confirm fresh starts")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if args.threads is not None:
        import torch

        torch.set_num_threads(args.threads)
    if args.families:
        names = args.families
    elif args.behaviours:
        names = [n for n, e in json.loads(args.behaviours.read_text())["families"].items() if not e["passed"]]
    else:
        raise SystemExit("give --behaviours or --families")
    fams = [f for f in B.families(names) if f.judge is not None]
    t0 = time.time()
    bfm = BFM.load(args.checkpoint)
    if args.judge:
        judge_saved(bfm, fams, args)
        return
    cands = pool(bfm, args.motions, args.random, args.frames, args.seed)
    labels, zs = list(cands), np.stack(list(cands.values()))
    print(f"{len(labels)} candidate z's, {time.time() - t0:.0f} s", flush=True)
    screen = judge_all(bfm, zs, B.start_states(1, args.seed), fams, args.steps, args.threads)
    print(f"screened in {time.time() - t0:.0f} s", flush=True)
    fresh = B.start_states(args.confirm, args.seed + 100)
    search_starts = B.start_states(2, args.seed + 50)
    report: dict[str, Any] = {"settings": vars(args) | {"out": str(args.out), "behaviours": str(args.behaviours),
                                                        "motions": [str(m) for m in args.motions]},
                              "candidates": len(labels), "families": {}}
    for f in fams:
        s = screen[f.name]
        order = np.lexsort((-s["measure"][:, 0], -s["pass"][:, 0]))
        top = [labels[i] for i in order[:3]]

        def score(batch: np.ndarray, f: B.Family = f) -> np.ndarray:
            r = judge_all(bfm, batch.astype(np.float32), search_starts, [f], args.steps, args.threads)[f.name]
            return r["pass"].mean(1) + 0.1 * np.tanh(r["measure"].mean(1))

        refined = cross_entropy(score, cands[top[0]], Search(generations=args.generations,
                                                             population=args.population, seed=args.seed))
        confirm = {lab: cands[lab] for lab in [f"reward:{f.prompt}", *top]} | {"cem": refined.z}
        c = judge_all(bfm, np.stack(list(confirm.values())), fresh, [f], args.steps, args.threads)[f.name]
        rows = {lab: {"pass": float(c["pass"][i].mean()), MEASURE[f.name][0]: float(MEASURE[f.name][1] *
                                                                                   c["measure"][i].mean())}
                for i, lab in enumerate(confirm)}
        best = max(rows.values(), key=lambda r: r["pass"])
        report["families"][f.name] = {
            "screen_passed": int(s["pass"][:, 0].sum()), "screen_top": {lab: {
                "pass": float(s["pass"][labels.index(lab), 0]),
                MEASURE[f.name][0]: float(MEASURE[f.name][1] * s["measure"][labels.index(lab), 0])} for lab in top},
            "cem_history": refined.history, "confirmed": rows,
            "verdict": "missing prompt" if best["pass"] >= B.PASS_SHARE else "missing skill"}
        args.out.write_text(json.dumps(report, indent=1))
        print(f"{f.name}: {report['families'][f.name]['verdict']}; screen passes {int(s['pass'][:, 0].sum())} of "
              f"{len(labels)}; confirmed {json.dumps(rows)} ({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
