"""Control steps per second of `fbcpr play`'s loop with a page connected, next to the bare env + policy rate.

    python benchmarks/play_speed.py [--seconds 10] [--threads 1] [--model pretrained]

One run serves the playground (the shipped model under the walk prompt), opens its page in headless Chromium (the
system's `chromium`, software WebGL, as the browser test does), and measures, with the page connected and drawing:
- `bare env + policy`: `HumanoidEnv.step(bfm.act(obs, z))` back to back, the reference;
- `play loop, flat out`: the playground's loop (step, reward for the plot, geoms posed and sent to the page,
  camera, readouts) without waiting between steps: what it could hold;
- `play loop, real time`: the loop as `fbcpr play` runs it, paced at 30 steps a second: what it holds.
The browser runs on the same cores, so on a small machine it competes with the loop, as it does for a user.
"""
from __future__ import annotations

import argparse
import os
import shutil
import time

import numpy as np
import torch

from fbcpr.apps.play.page import Playground
from fbcpr.apps.play.session import Prompts, Session
from fbcpr.inference.bfm import BFM
from humanoid_env.env import HumanoidEnv
from humanoid_env.tasks import TASKS, goal_names

WALK = "move-ego-0-2"


def bare_rate(bfm: BFM, seconds: float) -> float:
    """Env + policy steps per second, nothing else."""
    env = HumanoidEnv(action_mapping=bfm.action_mapping, max_episode_steps=10**9)
    z = bfm.prompt.reward(WALK)
    obs, _ = env.reset(seed=0)
    steps, start = 0, time.monotonic()
    while time.monotonic() - start < seconds:
        obs, *_ = env.step(bfm.act(obs, z))
        steps += 1
    return steps / (time.monotonic() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each measurement")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--model", default="pretrained")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from playwright.sync_api import sync_playwright

    bfm = BFM.load(args.model)
    prompts = Prompts(bfm)
    page = Playground(Session(bfm, prompts.reward(WALK)), prompts, sorted(TASKS), goal_names(), {}, port=8090)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "needs the system's chromium (apt-get install chromium)"
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium,
                                     args=["--use-gl=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"])
        tab = browser.new_page(viewport={"width": 1100, "height": 700})
        tab.goto(page.url)
        tab.locator("p").filter(has_text="z from:").wait_for(timeout=60_000)
        page.run(seconds=1.0)  # warm up: the page has its scene and starts drawing frames
        rows = [("bare env + policy", bare_rate(bfm, args.seconds)),
                ("play loop, flat out", page.run(seconds=args.seconds, realtime=False))]
        ticks: list[float] = []
        tick = page.tick
        page.tick = lambda: ticks.append(time.monotonic()) or tick()  # type: ignore[method-assign]
        rows.append(("play loop, real time", page.run(seconds=args.seconds, realtime=True)))
        gaps = np.diff(ticks)
        connected = len(page.server.get_clients())
        browser.close()
    page.stop()
    print(f"{args.seconds:g} s each, torch threads {args.threads}, {connected} page(s) connected (headless Chromium, "
          f"software WebGL), {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end")
    for name, rate in rows:
        print(f"  {name:22s} {rate:8.1f} steps/s   {rate / rows[0][1]:5.2f} x bare")
    print(f"real time: steps {1000 * np.median(gaps):.1f} ms apart (median), longest gap {1000 * gaps.max():.0f} ms, "
          f"{int((gaps > 0.1).sum())} gaps over 100 ms")


if __name__ == "__main__":
    main()
