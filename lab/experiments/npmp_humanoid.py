"""NPMP on the humanoid (issue 76, item 1): an NPMP distilled from the shipped model on the tracking split's training
takes only (lab/splits/train-tracking.txt, imported flat in data/clips/tracking/train), then

- `track`: one-shot tracking of the held-out split (lab/splits/heldout-tracking.txt) through the NPMP's encoder,
  next to the expert's own zero-shot tracking and the first-pose floor, with heldout_tracking.py's measures
  (MPJPE and EMD against the floor, falls), clip by clip and in the mean;
- `reuse`: one TD3 run (fbcpr/configs/td3-cpu.yaml on `--task`) either on raw actions or in the NPMP's latent
  space (`env.npmp`), evaluated every `--eval-every` env steps (10 episodes of 300 steps from the env's initial
  state, deterministic policy), its curve written to OUT/<agent>-seed<k>/curve.json; one run per call, so runs go
  one at a time;
- `plot`: both agents' curves in one figure (npmp_reuse_toy.py's panel) and RESULT lines;
- diagnostics: `expert-ref` (the NPMP tracking the expert's own rollouts of the takes instead of the clips) and
  `upright` (the share of upright steps of each run's last policy and of random ones in both action spaces).

    fbcpr npmp distill pretrained --motions data/clips/tracking/train --out runs/s72/npmp-bc --method bc \\
        --preset cpu --rollouts 8 --max-steps 200 --steps 15000 --checkpoint-every 2500 --seed 0
    python lab/experiments/npmp_humanoid.py track runs/s72/npmp-bc --seed 6901 --out runs/s72/track.json
    for s in 0 1 2; do for a in td3-raw td3-npmp; do
        python lab/experiments/npmp_humanoid.py reuse runs/s72/npmp-bc --agent $a --seed $s --out runs/s72/reuse
    done; done
    python lab/experiments/npmp_humanoid.py plot runs/s72/reuse --png lab/img/npmp_humanoid_reuse.png
    python lab/experiments/npmp_humanoid.py upright runs/s72/reuse
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from heldout_tracking import diagnose, summarise  # sibling scripts: the held-out measures, the toy's TD3 runs
from npmp_reuse_toy import plot_panel, random_reference, run
from tracking_split import clip_file, read_split

from fbcpr.cli.prompt_cmd import rollout
from fbcpr.core.checkpoint import load_checkpoint
from fbcpr.core.config import find_config, load_config
from fbcpr.envs.bundle import make_env
from fbcpr.eval.rollout import rollout as step_through
from fbcpr.inference.agents import load_tracker
from fbcpr.inference.bfm import BFM, resolve_checkpoint
from humanoid_env.env import FALLEN_HEIGHT
from motions.clip import Clip, load_clip

EPISODES, HORIZON = 10, 300
AGENTS = ("td3-raw", "td3-npmp")


def track(args: argparse.Namespace) -> None:
    """Each held-out take tracked by the expert (zero-shot) and by the NPMP (one-shot, its encoder's z's)."""
    npmp = load_tracker(args.npmp)
    expert = str(getattr(npmp, "info", {}).get("expert", "pretrained"))
    agents: dict[str, Any] = {"npmp": npmp}
    rows: dict[str, list[dict]] = {"bfm": [], "npmp": []}
    if args.expert_rows is None:
        agents["bfm"] = BFM.load(expert)
    else:  # the expert's rollouts are deterministic (lab/log.md 63): its recorded rows, same seed and code
        recorded = json.loads(args.expert_rows.read_text())
        if recorded["checkpoint"] != expert or recorded["seed"] != args.seed:
            raise SystemExit(f"{args.expert_rows}: {recorded['checkpoint']} at seed {recorded['seed']}, not {expert} "
                             f"at seed {args.seed}")
        rows["bfm"] = recorded["clips"]
    for take in read_split(args.split):
        clip = load_clip(clip_file(take, args.clips))
        for name, agent in agents.items():
            row = {**diagnose(agent, clip, args.seed), "take": take}
            rows[name].append(row)
            print(name, json.dumps(row), flush=True)
    if [r["take"] for r in rows["bfm"]] != [r["take"] for r in rows["npmp"]]:
        raise SystemExit("the expert's rows and the NPMP's are not the same takes in the same order")
    means = {name: summarise(r) for name, r in rows.items()}
    per_clip = {k: [n[k] / b[k] for n, b in zip(rows["npmp"], rows["bfm"])] for k in ("mpjpe", "emd")}
    relative = {"mpjpe": means["npmp"]["mpjpe"] / means["bfm"]["mpjpe"],
                "emd": means["npmp"]["emd"] / means["bfm"]["emd"],
                "mpjpe_median_per_clip": float(np.median(per_clip["mpjpe"])),
                "emd_median_per_clip": float(np.median(per_clip["emd"]))}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"npmp": args.npmp, "expert": expert, "seed": args.seed, "clips": rows,
                                    "means": means, "npmp_over_bfm": relative}, indent=1))
    print("| take | MPJPE floor | BFM | NPMP | NPMP / BFM | EMD floor | BFM | NPMP | NPMP / BFM | BFM | NPMP |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")
    for b, n in zip(rows["bfm"], rows["npmp"]):
        print(f"| {b['take'].removeprefix('cmu/')} | {b['mpjpe_floor']:.3f} | {b['mpjpe']:.3f} | {n['mpjpe']:.3f} | "
              f"{n['mpjpe'] / b['mpjpe']:.2f} | {b['emd_floor']:.2f} | {b['emd']:.2f} | {n['emd']:.2f} | "
              f"{n['emd'] / b['emd']:.2f} | {b['verdict']} | {n['verdict']} |")
    for name, m in means.items():
        print(f"RESULT method={name} split={args.split.stem} clips={m['clips']} mpjpe={m['mpjpe']:.3f} "
              f"mpjpe_floor={m['mpjpe_floor']:.3f} emd={m['emd']:.3f} emd_floor={m['emd_floor']:.3f} "
              f"falls={m['falls']}")
    print(f"NPMP / BFM: MPJPE {relative['mpjpe']:.2f}x (median per clip {relative['mpjpe_median_per_clip']:.2f}), "
          f"EMD {relative['emd']:.2f}x (median per clip {relative['emd_median_per_clip']:.2f})")


def expert_reference(args: argparse.Namespace) -> None:
    """Diagnostic: the NPMP tracking the expert's own rollout of each take (the kind of trajectory its encoder was
    trained on: BC data are the expert's visited states), next to tracking the clip itself."""
    npmp = load_tracker(args.npmp)
    expert = BFM.load(str(getattr(npmp, "info", {}).get("expert", "pretrained")))
    rows: dict[str, list[dict]] = {"clip": [], "expert_rollout": []}
    for take in read_split(args.split):
        clip = load_clip(clip_file(take, args.clips))
        ep = rollout(expert, expert.track_z(clip), seed=args.seed, start=(clip.qpos[0], clip.qvel[0]),
                     label=f"expert {clip.name}")
        own = Clip(qpos=np.stack(ep.qpos), qvel=np.stack(ep.qvel), obs=np.stack(ep.obs).astype(np.float32),
                   name=f"{clip.name}-expert")
        for name, ref in (("clip", clip), ("expert_rollout", own)):
            rows[name].append({**diagnose(npmp, ref, args.seed), "take": take})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"npmp": args.npmp, "seed": args.seed, "clips": rows}, indent=1))
    print("| take | NPMP on the clip: MPJPE / floor | verdict | on the expert's rollout: MPJPE / floor | verdict |")
    print("|---|---:|---|---:|---|")
    for c, e in zip(rows["clip"], rows["expert_rollout"]):
        print(f"| {c['take'].removeprefix('cmu/')} | {c['mpjpe']:.3f} / {c['mpjpe_floor']:.3f} | {c['verdict']} | "
              f"{e['mpjpe']:.3f} / {e['mpjpe_floor']:.3f} | {e['verdict']} |")
    for name, r in rows.items():
        m = summarise(r)
        print(f"reference {name}: MPJPE {m['mpjpe']:.3f} / floor {m['mpjpe_floor']:.3f} = {m['mpjpe_ratio']:.2f}x; "
              f"EMD {m['emd']:.2f} / floor {m['emd_floor']:.2f}; falls {m['falls']} of {m['clips']}")


def reuse_config(npmp: str | None, task: str, steps: int, eval_every: int, warmup: int, seed: int) -> Any:
    """td3-cpu.yaml on `task` at `steps` env steps, in the latent space of the NPMP checkpoint `npmp` if given."""
    cfg = load_config(find_config("td3-cpu"))
    env = cfg.env if npmp is None else replace(cfg.env, npmp=npmp)
    return replace(cfg, env=env, agent=replace(cfg.agent, reward=replace(cfg.agent.reward, task=task)),
                   train=replace(cfg.train, total_env_steps=steps, eval_every=eval_every, warmup_steps=warmup,
                                 checkpoint_every=eval_every * 2, seed=seed))


def reuse(args: argparse.Namespace) -> None:
    """One TD3 run; its curve (and the random policy's return in the same action space) to OUT/<agent>-seed<k>."""
    npmp = str(resolve_checkpoint(args.npmp)) if args.agent == "td3-npmp" else None
    cfg = reuse_config(npmp, args.task, args.steps, args.eval_every, args.warmup, args.seed)
    out = args.out / f"{args.agent}-seed{args.seed}"
    if (out / "curve.json").exists():
        print(f"{out}: done already")
        return
    steps, curve, seconds = run(cfg, out, args.task, args.seed, EPISODES, HORIZON)
    rand = random_reference(cfg, args.task, EPISODES, HORIZON)
    (out / "curve.json").write_text(json.dumps({"agent": args.agent, "seed": args.seed, "task": args.task,
                                                "npmp": npmp, "steps": steps, "curve": curve, "seconds": seconds,
                                                "random": rand}, indent=1))
    print(f"{args.agent} seed {args.seed} ({seconds:.0f} s): return " + " ".join(f"{r['return']:.1f}" for r in curve))


def upright_share(act: Any, bundle: Any, seed: int = 1000) -> float:
    """Share of the evaluation's steps (EPISODES x HORIZON, the return's starts) with the pelvis at or above the
    fallen height: how long a policy keeps the body up, for the return's upright factor."""
    env, heights = bundle.make_eval_env(EPISODES, HORIZON + 1), []
    try:
        obs, _ = env.reset(seed=seed)
        step_through(env, obs, lambda t, o: act(np.asarray(o, np.float32)), HORIZON,
                lambda step: heights.append(np.asarray(step.info["final_obs"])[:, 0]))
    finally:
        env.close()
    return float((np.stack(heights) >= FALLEN_HEIGHT).mean())


def upright(args: argparse.Namespace) -> None:
    """Upright share of each run's last checkpoint and of the random policy in each action space."""
    rows = []
    for path in sorted(args.runs.glob("*/curve.json")):
        c = json.loads(path.read_text())
        cfg = reuse_config(c["npmp"], c["task"], 1, 1, 1, c["seed"])
        bundle = make_env(cfg.env, 1, 0)
        model = load_checkpoint(resolve_checkpoint(str(path.parent)), "cpu").model
        rows.append((c["agent"], c["seed"], upright_share(lambda o: model.act(o, mean=True), bundle)))
        if c["agent"] not in {r[0] for r in rows[:-1]}:  # once per action space: the random policy
            rng = np.random.default_rng(0)
            rows.append((c["agent"], "random", upright_share(
                lambda o: rng.uniform(-1, 1, (len(o), bundle.action_dim)).astype(np.float32), bundle)))
    for agent, seed, share in rows:
        print(f"{agent} {seed}: upright {share:.3f}")


def plot(args: argparse.Namespace) -> None:
    """Both agents' curves (mean over seeds, min-max band, random policy dotted) in one figure; RESULT lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves: dict[str, Any] = {}
    for path in sorted(args.runs.glob("*/curve.json")):
        c = json.loads(path.read_text())
        entry = curves.setdefault(c["agent"], {"steps": c["steps"], "seeds": {}, "random": c["random"], "seconds": {}})
        entry["seeds"][c["seed"]], entry["seconds"][c["seed"]] = c["curve"], c["seconds"]
        task = c["task"]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    plot_panel(ax, {name: curves[name] for name in AGENTS if name in curves}, task, HORIZON)
    ax.set_title("Humanoid: TD3 in the NPMP's latent space vs raw actions\nmean, min-max band; dotted: random policy",
                 fontsize=10)
    fig.tight_layout()
    args.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=110)
    for name, c in curves.items():
        final = {s: rows[-1]["return"] for s, rows in sorted(c["seeds"].items())}
        print(f"RESULT method={'npmp' if name == 'td3-npmp' else 'td3'} agent={name} task={task} "
              f"env_steps={c['steps'][-1]} seeds={len(final)} return={np.mean(list(final.values())):.2f} "
              f"per_seed={','.join(f'{v:.2f}' for v in final.values())} random={c['random']['return']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("track", help="one-shot tracking of the held-out split, next to the expert and the floor")
    e = sub.add_parser("expert-ref", help="diagnostic: the NPMP tracking the expert's rollouts instead of the clips")
    for p in (t, e):  # both roll the NPMP out over the same split
        p.add_argument("npmp", help="an NPMP run directory or checkpoint")
        p.add_argument("--split", type=Path, default=Path("lab/splits/heldout-tracking.txt"))
        p.add_argument("--clips", type=Path, default=Path("data/clips/cmu-all"))
        p.add_argument("--seed", type=int, required=True)
        p.add_argument("--out", type=Path, required=True)
    t.add_argument("--expert-rows", type=Path, default=None,
                   help="heldout_tracking.py's JSON of the expert at the same seed, instead of rolling it out again")
    r = sub.add_parser("reuse", help="one TD3 run on raw actions or in the NPMP's latent space")
    r.add_argument("npmp", help="an NPMP run directory or checkpoint")
    r.add_argument("--agent", choices=AGENTS, required=True)
    r.add_argument("--seed", type=int, required=True)
    r.add_argument("--task", default="move-ego-90-2")
    r.add_argument("--steps", type=int, default=30_000, help="env steps of the run")
    r.add_argument("--eval-every", type=int, default=5_000)
    r.add_argument("--warmup", type=int, default=5_000, help="env steps of random actions before updates")
    r.add_argument("--out", type=Path, required=True)
    u = sub.add_parser("upright", help="share of upright steps of each run's last policy and of random ones")
    u.add_argument("runs", type=Path)
    p = sub.add_parser("plot", help="the learning curves of OUT/*/curve.json in one figure")
    p.add_argument("runs", type=Path)
    p.add_argument("--png", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    commands = {"track": track, "expert-ref": expert_reference, "reuse": reuse, "upright": upright, "plot": plot}
    commands[args.command](args)


if __name__ == "__main__":
    main()
