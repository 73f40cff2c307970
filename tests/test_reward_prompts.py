"""Reward prompts stored at export (`fbcpr.inference.reward_prompts`, `fbcpr export --store-prompts`)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import tiny_humanoid_checkpoint
from typer.testing import CliRunner

from fbcpr import BFM
from fbcpr.cli.app import app
from fbcpr.core.checkpoint import PROMPTS_FILE, CheckpointError, load_checkpoint, save_checkpoint
from fbcpr.core.errors import PromptError
from fbcpr.inference.interpolation import interpolate, with_reward_states
from fbcpr.inference.reward_prompts import RewardPrompts, infer_reward_prompts, weights_digest
from humanoid_env.tasks.rewards import TASKS

torch.set_num_threads(1)
ALL_STATES = 10**6  # n above the buffer size: the whole buffer, and not the stored prompt (n is not the default)


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A model exported with 16 of its 64 pooled states kept and prompts stored from all 64."""
    root = tmp_path_factory.mktemp("prompts")
    model, donor = tiny_humanoid_checkpoint(root, "model", seed=0), tiny_humanoid_checkpoint(root, "donor", seed=1)
    out = root / "export"
    res = CliRunner().invoke(app, ["export", str(model), str(out), "--reward-states-from", str(model),
                                   "--reward-states-from", str(donor), "--reward-samples", "16", "--full",
                                   "--store-prompts"])
    assert res.exit_code == 0, res.output
    assert "from 64 states" in res.output
    return model, donor, out


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))


def test_a_named_prompt_is_the_one_inferred_from_every_state_not_from_the_kept_ones(exported):
    model, donor, out = exported
    got = BFM.load(out)
    pooled = with_reward_states(BFM.load(model), [BFM.load(model), BFM.load(donor)])
    assert len(got.reward_buffer["qpos"]) == 16 and got.reward_prompts.states == 64
    stored = [t for t in TASKS if t in got.reward_prompts.z]
    assert len(stored) >= 20
    for task in stored:
        z = got.prompt.reward(task)
        np.testing.assert_allclose(z, pooled.prompt.reward(task, n=ALL_STATES), atol=1e-5)
        assert z.dtype == np.float32 and np.isclose(np.linalg.norm(z), np.sqrt(got.z_dim), rtol=1e-4)
    cosines = []
    for task in stored:
        try:  # from the 16 kept states alone
            cosines.append(_cos(got.prompt.reward(task), got.prompt.reward(task, n=ALL_STATES)))
        except PromptError:  # they hold no state this task pays: the stored prompt still serves it
            continue
    assert len(cosines) >= 10 and min(cosines) < 0.99


def test_other_settings_a_user_reward_and_a_combined_name_use_the_kept_states(exported):
    _, _, out = exported
    got = BFM.load(out)
    task = next(t for t in TASKS if t in got.reward_prompts.z)
    plain = BFM(got.model, got.config, reward_buffer=got.reward_buffer)  # the same model and states, nothing stored
    assert plain.reward_prompts is None
    for kwargs in ({"temperature": 5.0}, {"method": "regression"}, {"seed": 3}, {"n": 8}):
        np.testing.assert_allclose(got.prompt.reward(task, **kwargs), plain.prompt.reward(task, **kwargs), atol=1e-6)
    from humanoid_env.tasks import get_reward

    fn = get_reward(task)
    np.testing.assert_allclose(got.prompt.reward(lambda *a: fn(*a)), plain.prompt.reward(task), atol=1e-6)
    combined = f"{task}*{task}"
    np.testing.assert_allclose(got.prompt.reward(combined), plain.prompt.reward(combined), atol=1e-6)


def test_tasks_the_states_do_not_pay_are_left_out_and_fail_as_before(exported):
    model, _, out = exported
    got = BFM.load(out)
    for task in set(TASKS) - set(got.reward_prompts.z):
        with pytest.raises(PromptError, match="zero on all"):
            got.prompt.reward(task)
    with pytest.raises(PromptError, match="no-such-task"):
        infer_reward_prompts(BFM.load(model), ["move-ego-0-0", "no-such-task"])


def test_prompts_round_trip_and_are_dropped_when_the_weights_change(exported, tmp_path):
    _, _, out = exported
    got = BFM.load(out)
    again = BFM.load(got.save(tmp_path / "again"))
    assert again.reward_prompts.z.keys() == got.reward_prompts.z.keys()
    for task, z in got.reward_prompts.z.items():
        np.testing.assert_array_equal(again.reward_prompts.z[task], z)
    with torch.no_grad():
        next(got.model.parameters()).add_(0.01)
    changed = got.save(tmp_path / "changed")
    assert not (changed / PROMPTS_FILE).exists() and BFM.load(changed).reward_prompts is None
    assert interpolate(BFM.load(out), BFM.load(out), 0.5).reward_prompts is None   # new weights, none carried
    assert with_reward_states(BFM.load(out), [BFM.load(out)]).reward_prompts is None  # new states likewise


def _resave(src: Path, dst: Path, prompts: tuple[dict, dict], model: torch.nn.Module | None = None) -> Path:
    ckpt = load_checkpoint(src)
    return save_checkpoint(dst, model if model is not None else ckpt.model, ckpt.config,
                           reward_buffer=ckpt.reward_buffer(), reward_prompts=prompts)


def test_prompts_of_other_weights_are_refused_on_load(exported, tmp_path):
    model, _, out = exported
    stored = BFM.load(out).reward_prompts.to_tensors()
    other = _resave(out, tmp_path / "other", stored, model=load_checkpoint(model.parent / "donor").model)
    with pytest.raises(CheckpointError, match=f"{PROMPTS_FILE}.*other weights"):
        BFM.load(other)


@pytest.mark.parametrize("case, match", [
    ("nan", "finite"), ("shape", "finite"), ("name", "unknown|not"), ("temperature", "temperature"),
    ("states", "states"), ("many", "at most 3"), ("revisions", "'revisions' must map stored task names"),
])
def test_malformed_stored_prompts_are_named(exported, tmp_path, monkeypatch, case, match):
    import fbcpr.inference.reward_prompts as rp

    _, _, out = exported
    tensors, meta = BFM.load(out).reward_prompts.to_tensors()
    if case == "many":
        monkeypatch.setattr(rp, "MAX_PROMPTS", 3)
    first = next(iter(tensors))
    if case == "nan":
        tensors[first] = torch.full_like(tensors[first], float("nan"))
    elif case == "shape":
        tensors[first] = tensors[first][:-1]
    elif case == "name":
        tensors["no-such-task"] = tensors[first].clone()
    elif case == "temperature":
        meta["temperature"] = 3.0
    elif case == "states":
        meta["states"] = 0
    elif case == "revisions":
        meta["revisions"] = {"no-such-task": {"sitonground": 1}}
    bad = _resave(out, tmp_path / case, (tensors, meta))
    with pytest.raises(CheckpointError, match=match) as err:
        BFM.load(bad)
    assert PROMPTS_FILE in str(err.value)


def test_a_corrupted_prompts_file_is_caught_by_its_checksum(exported, tmp_path):
    import shutil

    _, _, out = exported
    copy = Path(shutil.copytree(out, tmp_path / "copy"))
    data = bytearray((copy / PROMPTS_FILE).read_bytes())
    data[-5] ^= 0xFF
    (copy / PROMPTS_FILE).write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="checksum"):
        BFM.load(copy)


def test_the_digest_follows_every_tensor(exported):
    _, _, out = exported
    model = BFM.load(out).model
    before = weights_digest(model)
    assert before == weights_digest(BFM.load(out).model)
    with torch.no_grad():
        model.obs_normalizer.mean.add_(1e-6)
    assert weights_digest(model) != before


def test_store_prompts_is_refused_for_a_model_without_the_humanoid_tasks(tmp_path):
    from fbcpr.core.config import config_from_dict
    from fbcpr.methods.fb_cpr.model import FBCPRModel

    cfg = config_from_dict({"model": {"preset": "tiny", "obs_dim": 4, "action_dim": 2},
                            "env": {"name": "toy"}})
    src = save_checkpoint(tmp_path / "toy", FBCPRModel(cfg.model), cfg,
                          reward_buffer={"next_obs": np.zeros((4, 4)), "qpos": np.zeros((4, 2)),
                                         "qvel": np.zeros((4, 2))})
    res = CliRunner().invoke(app, ["export", str(src), str(tmp_path / "out"), "--store-prompts"])
    assert res.exit_code != 0 and "--store-prompts" in res.output and "toy" in res.output


def test_reward_prompts_to_tensors_records_what_loading_checks():
    z = {"move-ego-0-0": np.ones(4, np.float32)}
    tensors, meta = RewardPrompts(z, 7, "abc").to_tensors()
    assert meta == {"states": 7, "digest": "abc", "method": "weighted", "temperature": 10.0, "refined": {},
                    "revisions": {}}
    assert torch.equal(tensors["move-ego-0-0"], torch.ones(4))


def test_stored_prompts_travel_to_the_hub_folder_and_the_card_names_them(exported, tmp_path):
    from fbcpr.inference.bfm import HUB_FILES

    _, _, out = exported
    folder = BFM.load(out).save_for_hub(tmp_path / "hub", repo_id="me/bfm")
    assert PROMPTS_FILE in HUB_FILES and (folder / PROMPTS_FILE).is_file()
    n = len(BFM.load(out).reward_prompts.z)
    assert f"stored reward prompts: {n} named tasks, inferred from 64 states" in (folder / "README.md").read_text()
    assert BFM.load(folder).reward_prompts.states == 64


def test_more_states_than_the_bound_are_refused_before_any_work(exported, monkeypatch):
    import fbcpr.inference.reward_prompts as rp
    from fbcpr.core.errors import InputError

    model, _, _ = exported
    monkeypatch.setattr(rp, "MAX_STATES", 31)
    bfm = BFM.load(model)  # 32 states
    monkeypatch.setattr(bfm, "backward", lambda *a, **k: pytest.fail("B was computed"))
    with pytest.raises(InputError, match="32 reward states.*at most 31.*--reward-states-from"):
        infer_reward_prompts(bfm, ["move-ego-0-0"])


def test_fbcpr_prompt_says_whether_the_reward_prompt_was_stored(exported):
    model, _, out = exported
    task = next(t for t in TASKS if t in BFM.load(out).reward_prompts.z)
    stored = CliRunner().invoke(app, ["prompt", str(out), "--reward", task, "--steps", "2"])
    assert stored.exit_code == 0, stored.output
    assert "stored at export (from 64 states)" in stored.output
    for args in (["prompt", str(out), "--reward", task, "--steps", "2", "--method", "regression"],
                 ["prompt", str(model), "--reward", task, "--steps", "2"]):
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        assert "inferred from the checkpoint's reward states" in res.output and "stored at export" not in res.output


def test_stored_reward_answers_only_for_the_default_settings_of_a_stored_name(exported):
    _, _, out = exported
    got = BFM.load(out)
    task = next(iter(got.reward_prompts.z))
    np.testing.assert_array_equal(got.prompt.stored_reward(f"  {task} "), got.reward_prompts.z[task])
    assert got.prompt.stored_reward(task, temperature=1.0) is None
    assert got.prompt.stored_reward(f"{task}*{task}") is None
    assert got.prompt.stored_reward(lambda *a: np.ones(1)) is None
    z = got.prompt.stored_reward(task)
    z[:] = 0  # a copy: the stored prompt is untouched
    assert np.any(got.prompt.reward(task) != 0)


REFINE = ["--refine", "1", "--refine-population", "2", "--refine-starts", "1", "--refine-steps", "3"]


@pytest.fixture(scope="module")
def refined(exported, tmp_path_factory) -> tuple[Path, str]:
    """The exported model again, with one stored prompt refined by a two-z search of 3-step episodes."""
    _, _, out = exported
    task = next(t for t in TASKS if t in BFM.load(out).reward_prompts.z)
    dst = tmp_path_factory.mktemp("refined") / "model"
    res = CliRunner().invoke(app, ["export", str(out), str(dst), "--reward-samples", "16", "--full",
                                   "--refine-prompts", task, *REFINE])
    assert res.exit_code == 0, res.output
    assert f"refined {task}: mean reward on its starts" in res.output
    return dst, task


def test_a_refined_prompt_answers_by_default_and_keeps_its_zero_shot_z(exported, refined):
    _, _, out = exported
    dst, task = refined
    before, got = BFM.load(out), BFM.load(dst)
    record = got.reward_prompts.refined[task]
    assert set(got.reward_prompts.refined) == {task}
    assert {k: record[k] for k in ("generations", "population", "starts", "steps", "seed")} == {
        "generations": 1, "population": 2, "starts": 1, "steps": 3, "seed": 0}
    assert record["score"] >= record["score0"]  # the search keeps the best mean it scored, z0 among them
    zero_shot = before.prompt.reward(task)
    np.testing.assert_array_equal(got.prompt.reward(task, refined=False), zero_shot)
    np.testing.assert_array_equal(got.prompt.reward(task), got.reward_prompts.z[task])
    assert np.isclose(np.linalg.norm(got.prompt.reward(task)), np.sqrt(got.z_dim), rtol=1e-4)
    for other in set(got.reward_prompts.z) - {task}:  # the others untouched
        np.testing.assert_array_equal(got.prompt.reward(other), before.prompt.reward(other))
        np.testing.assert_array_equal(got.prompt.reward(other, refined=False), before.prompt.reward(other))
    again = BFM.load(got.save(dst.parent / "again"))  # the record travels with a save
    np.testing.assert_array_equal(again.prompt.reward(task), got.prompt.reward(task))
    np.testing.assert_array_equal(again.reward_prompts.refined[task]["z0"], zero_shot)
    assert f"refined by rollouts: {task}" in got.save_for_hub(dst.parent / "hub").joinpath("README.md").read_text()


def test_the_refined_z_is_the_one_prompt_refine_finds(exported, refined):
    """The export's search and `fbcpr prompt --refine`'s are one search: the same starts, seed and z0."""
    from fbcpr.inference.refine import Search, refine, reward_objective, standing_starts

    _, _, out = exported
    dst, task = refined
    bfm = BFM.load(out)
    got = refine(bfm, bfm.prompt.reward(task), reward_objective(task), standing_starts(1, 1), steps=3,
                 search=Search(generations=1, population=2, seed=0))
    np.testing.assert_allclose(BFM.load(dst).prompt.reward(task), got.z, atol=1e-6)


def test_prompt_names_a_refined_prompt(refined):
    dst, task = refined
    res = CliRunner().invoke(app, ["prompt", str(dst), "--reward", task, "--steps", "3"])
    assert res.exit_code == 0, res.output
    assert "refined by 1 generations" in " ".join(res.output.split()), res.output  # the table may wrap after


@pytest.mark.parametrize("args, match", [
    (["--refine", "2"], "--refine: only mean"),
    (["--refine-prompts", "no-such-task"], "no-such-task not among the named tasks"),
    (["--refine-prompts", "move-ego-0-0", "--refine-population", "4096", "--refine-starts", "2"], "more than 4096"),
])
def test_refine_prompts_options_are_checked_before_any_work(exported, tmp_path, args, match):
    _, _, out = exported
    res = CliRunner().invoke(app, ["export", str(out), str(tmp_path / "out"), *args])
    assert res.exit_code != 0 and match in " ".join(res.output.split()), res.output
    assert not (tmp_path / "out").exists()


def test_refining_needs_stored_prompts(exported, tmp_path):
    model, _, out = exported
    res = CliRunner().invoke(app, ["export", str(model), str(tmp_path / "out"), "--refine-prompts", "move-ego-0-0",
                                   *REFINE])
    assert res.exit_code != 0 and "--store-prompts" in res.output
    assert not (tmp_path / "out").exists()
    unstored = next(t for t in TASKS if t not in BFM.load(out).reward_prompts.z)  # its states pay this task nothing
    res = CliRunner().invoke(app, ["export", str(out), str(tmp_path / "out"), "--refine-prompts", unstored, *REFINE])
    assert res.exit_code != 0 and f"no stored prompt to refine for {unstored}" in " ".join(res.output.split())
    assert not (tmp_path / "out").exists()


def test_a_search_can_start_from_a_saved_z(exported, tmp_path):
    """--refine-from: the search starts from a z found some other way; the record keeps it beside the zero-shot z."""
    from fbcpr.inference.refine import Search, project, refine, reward_objective, standing_starts

    _, _, out = exported
    bfm = BFM.load(out)
    task, other = [t for t in TASKS if t in bfm.reward_prompts.z][:2]
    start = (0.5 * bfm.prompt.reward(other)).astype(np.float32)  # off the sphere: the search projects it
    np.save(tmp_path / "start.npy", start)
    dst = tmp_path / "model"
    res = CliRunner().invoke(app, ["export", str(out), str(dst), "--reward-samples", "16", "--full",
                                   "--refine-prompts", task, "--refine-from", f"{task}={tmp_path / 'start.npy'}",
                                   *REFINE])
    assert res.exit_code == 0, res.output
    got = BFM.load(dst)
    record = got.reward_prompts.refined[task]
    np.testing.assert_allclose(record["start"], project(start), atol=1e-5)
    np.testing.assert_array_equal(record["z0"], bfm.prompt.reward(task))  # the zero-shot z stays the zero-shot z
    same = refine(bfm, start, reward_objective(task), standing_starts(1, 1), steps=3,
                  search=Search(generations=1, population=2, seed=0))
    np.testing.assert_allclose(got.prompt.reward(task), same.z, atol=1e-6)
    assert record["score0"] == pytest.approx(same.score0)  # the start's score, not the zero-shot z's
    again = BFM.load(got.save(tmp_path / "again"))  # the start travels with a save
    np.testing.assert_array_equal(again.reward_prompts.refined[task]["start"], record["start"])


@pytest.mark.parametrize("case, match", [
    ("form", "expected TASK=Z.npy"), ("task", "is not among --refine-prompts"), ("missing", "is not a file"),
    ("shape", "must hold one finite float z of shape"), ("pickle", "is not a .npy array"),
    ("alone", "only mean something with --refine-prompts"),
])
def test_refine_from_is_checked_and_names_its_file(exported, tmp_path, case, match):
    _, _, out = exported
    bfm = BFM.load(out)
    task = next(t for t in TASKS if t in bfm.reward_prompts.z)
    path = tmp_path / "z.npy"
    if case == "shape":
        np.save(path, np.ones(bfm.z_dim + 1, np.float32))
    elif case == "pickle":
        np.save(path, np.array([{"z": 1}], dtype=object), allow_pickle=True)
    else:
        np.save(path, np.ones(bfm.z_dim, np.float32))
    value = {"form": str(path), "task": f"move-ego-0-2-raisearms-h-h={path}", "missing": f"{task}={tmp_path / 'no.npy'}"
             }.get(case, f"{task}={path}")
    refining = [] if case == "alone" else ["--refine-prompts", task]
    res = CliRunner().invoke(app, ["export", str(out), str(tmp_path / "out"), *refining, "--refine-from", value,
                                   *REFINE])
    said = " ".join(res.output.split())
    assert res.exit_code != 0 and match in said, res.output
    if case in ("missing", "shape", "pickle"):
        assert "no.npy" in said or "z.npy" in said
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("case, match", [
    ("unstored", "stores no prompt"), ("key", "missing score"), ("z0", "finite"), ("type", "map task names"),
    ("start", "finite"),
])
def test_malformed_refinement_records_are_named(refined, tmp_path, case, match):
    dst, task = refined
    tensors, meta = BFM.load(dst).reward_prompts.to_tensors()
    if case == "unstored":
        meta["refined"]["no-such-task"] = meta["refined"][task]
    elif case == "key":
        del meta["refined"][task]["score"]
    elif case == "z0":
        meta["refined"][task]["z0"] = meta["refined"][task]["z0"][:-1]
    elif case == "start":
        meta["refined"][task]["start"] = [float("nan")] * len(meta["refined"][task]["z0"])
    else:
        meta["refined"] = [task]
    bad = _resave(dst, tmp_path / case, (tensors, meta))
    with pytest.raises(CheckpointError, match=match) as err:
        BFM.load(bad)
    assert PROMPTS_FILE in str(err.value)


def test_the_reward_suite_marks_a_refined_prompt(refined, exported, tmp_path):
    import json

    dst, task = refined
    other = next(t for t in BFM.load(dst).reward_prompts.z if t != task)
    res = CliRunner().invoke(app, ["eval", str(dst), "--suite", "reward", "--tasks", f"{task},{other}",
                                   "--episodes", "1", "--steps", "3", "--out", str(tmp_path / "eval")])
    assert res.exit_code == 0, res.output
    got = json.loads((tmp_path / "eval" / "results.json").read_text())["reward"]
    assert got[task]["prompt"] == "refined" and got[other]["prompt"] == "zero-shot"


def test_the_behaviour_checks_name_the_refined_prompts_they_ran(refined):
    from fbcpr.eval.behaviours import check, table

    dst, task = refined
    assert task == "move-ego-0-0"  # the first named task: the prompt of the stand family
    got = check({"model": BFM.load(dst)}, ["stand", "jump"], episodes=1, steps=60, show_progress=False)
    assert got["refined_prompts"] == ["move-ego-0-0"]
    assert "stored prompts refined at export: move-ego-0-0" in " ".join(str(table(got).title).split())


def test_a_prompt_stored_for_an_older_formula_is_inferred_again_with_a_warning(refined, tmp_path, monkeypatch):
    """Revising a task's formula makes the prompts stored for it stale: on load they are dropped, refinement
    included, and the task is inferred from the kept states under the new formula; an export stores it again."""
    import warnings

    from humanoid_env.tasks import get_reward

    dst, task = refined
    before = BFM.load(dst)
    monkeypatch.setattr(type(get_reward(task)), "revision", 1)  # the formula of `task`'s family revised
    recorded = before.reward_prompts.revisions
    revised = {t for t in before.reward_prompts.z if get_reward(t).revisions() != recorded.get(t, {})}
    assert task in revised and len(revised) < len(before.reward_prompts.z)
    with pytest.warns(UserWarning, match=f"older formula.*{task}"):
        got = BFM.load(dst)
    assert set(got.reward_prompts.z) == set(before.reward_prompts.z) - revised and not got.reward_prompts.refined
    plain = BFM(got.model, got.config, reward_buffer=got.reward_buffer)
    np.testing.assert_array_equal(got.prompt.reward(task), plain.prompt.reward(task))
    for kept in got.reward_prompts.z:
        np.testing.assert_array_equal(got.prompt.reward(kept), before.prompt.reward(kept))
    res = CliRunner().invoke(app, ["prompt", str(dst), "--reward", task, "--steps", "3"])
    said = " ".join(res.output.split())
    assert res.exit_code == 0 and f"warning: {dst / PROMPTS_FILE}: stored for an older formula" in said, res.output
    assert "inferred from the checkpoint's reward states" in said and "bfm.py" not in said  # one line, no source
    res = CliRunner().invoke(app, ["export", str(dst), str(tmp_path / "again"), "--store-prompts", "--full"])
    assert res.exit_code == 0, res.output
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = BFM.load(tmp_path / "again")
    stored = again.reward_prompts
    assert revised & set(stored.z)
    assert {t: stored.revisions.get(t, {}) for t in stored.z} == {t: get_reward(t).revisions() for t in stored.z}


def test_store_prompts_says_which_refined_prompts_it_replaces(refined, tmp_path):
    dst, task = refined
    res = CliRunner().invoke(app, ["export", str(dst), str(tmp_path / "out"), "--store-prompts", "--full"])
    said = " ".join(res.output.split())
    assert res.exit_code == 0 and f"warning: --store-prompts replaces the refined prompts of {task}" in said, said
    assert f"add --refine-prompts {task}" in said and not BFM.load(tmp_path / "out").reward_prompts.refined
    res = CliRunner().invoke(app, ["export", str(dst), str(tmp_path / "kept"), "--store-prompts", "--full",
                                   "--refine-prompts", task, *REFINE])
    assert res.exit_code == 0 and "replaces the refined" not in res.output, res.output
    assert set(BFM.load(tmp_path / "kept").reward_prompts.refined) == {task}
