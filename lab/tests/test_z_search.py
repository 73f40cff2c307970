"""The z search's pool and judge on the shipped model: every prompt kind is in the pool, each candidate is judged
per episode (the walk prompt moves where the stand prompt stands still), and saved z's are judged beside the
family's prompt."""
from __future__ import annotations

import argparse
import json

import numpy as np

import z_search
from fbcpr import BFM
from fbcpr.eval import behaviours as B
from humanoid_env.tasks import GOALS, TASKS


def test_pool_holds_every_prompt_kind() -> None:
    bfm = BFM.pretrained()
    cands = z_search.pool(bfm, [], n_random=3, frames_per_clip=2, seed=0)
    kinds = {label.split(":")[0] for label in cands}
    assert kinds == {"reward", "goal", "random"} and len(cands) == len(TASKS) + len(GOALS) + 3
    norms = np.linalg.norm(np.stack(list(cands.values())), axis=1)
    assert np.allclose(norms, np.sqrt(bfm.z_dim), rtol=1e-3)  # every candidate on the training sphere


def test_judge_all_scores_each_z_per_episode() -> None:
    bfm = BFM.pretrained()
    zs = np.stack([bfm.prompt.reward("move-ego-0-0"), bfm.prompt.reward("move-ego-0-2")])
    fams = B.families(["stand", "walk"])
    out = z_search.judge_all(bfm, zs, B.start_states(2, 0), fams, steps=300)
    assert out["stand"]["pass"].shape == (2, 2) and out["walk"]["measure"].shape == (2, 2)
    assert out["stand"]["pass"][0].all()  # the stand prompt stands still after a push (the family's start)
    assert out["walk"]["measure"][1].mean() > out["walk"]["measure"][0].mean() + 0.5  # the walk prompt moves


def test_judge_saved_z_beside_the_prompt(tmp_path) -> None:
    bfm = BFM.pretrained()
    np.save(tmp_path / "walk.npy", bfm.prompt.reward("move-ego-0-2"))
    args = argparse.Namespace(judge=[tmp_path / "walk.npy"], confirm=2, seed=0, steps=90, threads=1,
                              out=tmp_path / "judged.json")
    z_search.judge_saved(bfm, B.families(["walk"]), args)
    rows = json.loads(args.out.read_text())["walk"]
    assert list(rows) == ["reward:move-ego-0-2", str(tmp_path / "walk.npy")]
    assert rows["reward:move-ego-0-2"] == rows[str(tmp_path / "walk.npy")]  # the same z on the same starts
