"""lab/experiments/compare_targets.py: candidates against a base, seed by seed, from targets.py --out files."""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).parents[1] / "experiments" / "compare_targets.py"
spec = importlib.util.spec_from_file_location("compare_targets", SCRIPT)
compare_targets = importlib.util.module_from_spec(spec)
spec.loader.exec_module(compare_targets)


def targets_file(path: Path, name: str, seed: int, returns: dict, **measures) -> Path:
    """A file shaped like targets.py --out: the floors, one model row and the settings."""
    floor = {"returns": {t: 0.0 for t in returns}, "beats_floors": None}
    row = {"move-ego-0-2": returns["move-ego-0-2"], "returns": returns, "beats_floors": 1, "goal_success": 0.1,
           "tracking_emd": 5.0, "upright_median_s": 10.0, "got_up": 0.0} | measures
    settings = {"motions": "clips", "episodes": 4, "steps": 300, "seed": seed}
    path.write_text(json.dumps({"zero": floor, "random": floor, name: row, "settings": settings}))
    return path


def two_seeds(folder: Path, name: str, walk: float, jump: float, **measures) -> list[Path]:
    """A model's files for evaluation seeds 0 and 1: a walk return of `walk` + seed and a jump return of `jump`."""
    return [targets_file(folder / f"{name}{s}.json", name, s, {"move-ego-0-2": walk + s, "jump-2": jump}, **measures)
            for s in (0, 1)]


def test_per_seed_measures_sums_and_tasks_above_the_base(tmp_path):
    base = [targets_file(tmp_path / f"b{s}.json", "base", s, {"move-ego-0-2": 10.0, "jump-2": 5.0}) for s in (0, 1)]
    cand = [targets_file(tmp_path / "c0.json", "cand", 0, {"move-ego-0-2": 20.0, "jump-2": 1.0}, goal_success=0.3),
            targets_file(tmp_path / "c1.json", "cand", 1, {"move-ego-0-2": 30.0, "jump-2": 6.0}, beats_floors=2)]
    res = compare_targets.compare(base, cand)
    assert res["walk"] == [20.0, 30.0]
    assert res["sum"] == [21.0, 36.0]
    assert res["> base"] == [1, 2]           # seed 0: walk only; seed 1: walk and jump
    assert res["goal"] == [0.3, 0.1]
    assert res["tasks > floors"] == [1, 2]


def test_refuses_files_of_other_seeds_or_counts(tmp_path):
    base = [targets_file(tmp_path / "b0.json", "base", 0, {"move-ego-0-2": 1.0})]
    other_seed = targets_file(tmp_path / "c.json", "cand", 3, {"move-ego-0-2": 1.0})
    with pytest.raises(SystemExit, match="measured with"):
        compare_targets.compare(base, [other_seed])
    with pytest.raises(SystemExit, match="one per seed"):
        compare_targets.compare(base, [other_seed, other_seed])
    other_tasks = targets_file(tmp_path / "d.json", "cand", 0, {"move-ego-0-2": 1.0, "jump-2": 2.0})
    with pytest.raises(SystemExit, match="tasks differ"):
        compare_targets.compare(base, [other_tasks])


def test_a_file_that_is_not_a_targets_output_is_named(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SystemExit, match="bad.json"):
        compare_targets.model_row(bad)
    two_models = tmp_path / "two.json"
    two_models.write_text(json.dumps({"a": {}, "b": {}, "settings": {}}))
    with pytest.raises(SystemExit, match="one model row"):
        compare_targets.model_row(two_models)
    no_returns = tmp_path / "partial.json"
    no_returns.write_text(json.dumps({"m": {"move-ego-0-2": 1.0}, "settings": {}}))
    with pytest.raises(SystemExit, match="partial.json: the row 'm' has no beats_floors, goal_success"):
        compare_targets.model_row(no_returns)


def test_command_line_prints_each_model_with_its_mean(tmp_path):
    base = targets_file(tmp_path / "b.json", "base", 0, {"move-ego-0-2": 10.0})
    cand = targets_file(tmp_path / "c.json", "cand", 0, {"move-ego-0-2": 40.0})
    out = subprocess.run([sys.executable, str(SCRIPT), "--base", str(base), "--candidate", "A", str(cand)],
                         capture_output=True, text=True, check=True).stdout
    assert "walk 10.0 (10.0)" in out.splitlines()[1]
    assert out.splitlines()[2].startswith("A") and "walk 40.0 (40.0)" in out and "> base 1 (1.0)" in out


def test_the_shipping_rule_names_each_clause_a_candidate_fails(tmp_path):
    base = compare_targets.compare(*[[targets_file(tmp_path / "b.json", "base", 0,
                                                   {"move-ego-0-2": 10.0, "jump-2": 5.0}, beats_floors=40)]] * 2)
    def cand(name, returns, **measures):
        return compare_targets.compare([tmp_path / "b.json"],
                                       [targets_file(tmp_path / f"{name}.json", name, 0, returns, **measures)])

    better = cand("better", {"move-ego-0-2": 11.0, "jump-2": 5.0}, beats_floors=40, goal_success=0.1, tracking_emd=5.1)
    assert compare_targets.rule_failures(base, better, 95, 89) == []
    assert compare_targets.rule_failures(base, better, 95, 88) == ["pushes"]
    worse = cand("worse", {"move-ego-0-2": 10.0, "jump-2": 4.0}, beats_floors=39, goal_success=0.09,
                 tracking_emd=5.11)
    assert compare_targets.rule_failures(base, worse, 95, 95) == ["walk", "sum", "tasks", "goal", "EMD"]


def test_the_rule_is_printed_for_candidates_with_pushes(tmp_path, capsys, monkeypatch):
    b = targets_file(tmp_path / "b.json", "base", 0, {"move-ego-0-2": 10.0})
    c = targets_file(tmp_path / "c.json", "cand", 0, {"move-ego-0-2": 12.0})
    argv = ["compare_targets.py", "--base", str(b), "--candidate", "C", str(c), "--pushes", "base", "95"]
    monkeypatch.setattr("sys.argv", argv + ["--pushes", "C", "80"])
    compare_targets.main()
    assert "rule: fails pushes" in capsys.readouterr().out
    monkeypatch.setattr("sys.argv", argv + ["--pushes", "D", "80"])
    with pytest.raises(SystemExit):
        compare_targets.main()
    assert "no model named 'D'" in capsys.readouterr().err


def test_pushes_are_summed_from_upright_time_out_files(tmp_path, capsys, monkeypatch):
    """A real upright_time.py run writes the held pushed starts that the rule reads; mixed settings are refused."""
    up = str(Path(__file__).parents[1] / "experiments" / "upright_time.py")
    run = subprocess.run([sys.executable, up, "pretrained", "--episodes", "2", "--steps", "15", "--seed", "1",
                          "--push", "0.1", "0.3", "--out", str(tmp_path / "s1.json")],
                         capture_output=True, text=True, check=True).stdout
    printed = [line for line in run.splitlines() if "pushed start" in line][-1]   # the model's row, after the floors
    held = int(printed.split("whole 0.5 s: ")[1].split("/")[0])
    data = json.loads((tmp_path / "s1.json").read_text())
    assert data["pretrained"]["pushed_held"] == held and len(data["pretrained"]["seconds"]) == 2
    data["settings"]["seed"] = 2
    (tmp_path / "s2.json").write_text(json.dumps(data))
    assert compare_targets.pushes_held([tmp_path / "s1.json", tmp_path / "s2.json"]) == 2 * held
    with pytest.raises(SystemExit, match="seed 1 is in another file"):
        compare_targets.pushes_held([tmp_path / "s1.json", tmp_path / "s1.json"])
    data["settings"]["push"] = [0.2, 0.3]
    (tmp_path / "other.json").write_text(json.dumps(data))
    with pytest.raises(SystemExit, match="other.json: measured with"):
        compare_targets.pushes_held([tmp_path / "s1.json", tmp_path / "other.json"])
    unpushed = {k: v for k, v in data["pretrained"].items() if k != "pushed_held"}
    (tmp_path / "unpushed.json").write_text(json.dumps({**data, "pretrained": unpushed}))
    with pytest.raises(SystemExit, match="unpushed.json: not an upright_time.py --out file measured with --push"):
        compare_targets.pushes_held([tmp_path / "unpushed.json"])

    b = targets_file(tmp_path / "b.json", "base", 0, {"move-ego-0-2": 10.0})
    c = targets_file(tmp_path / "c.json", "cand", 0, {"move-ego-0-2": 12.0})
    argv = ["compare_targets.py", "--base", str(b), "--candidate", "C", str(c), "--pushes", "base", str(2 * held + 7)]
    monkeypatch.setattr("sys.argv", argv + ["--pushes", "C", str(tmp_path / "s1.json"), str(tmp_path / "s2.json")])
    compare_targets.main()
    assert f"pushes {2 * held}/128  rule: fails pushes" in capsys.readouterr().out
    monkeypatch.setattr("sys.argv", argv + ["--pushes", "C", "80", str(tmp_path / "s1.json")])
    with pytest.raises(SystemExit):
        compare_targets.main()
    assert "--pushes C: give one count" in capsys.readouterr().err


def test_noise_copies_set_a_floor_that_widens_every_margin_of_the_rule(tmp_path, capsys, monkeypatch):
    base = two_seeds(tmp_path, "base", 10.0, 5.0, beats_floors=40, goal_success=0.1, tracking_emd=5.0)
    copies = [two_seeds(tmp_path, "p", 12.0, 5.0, beats_floors=40, goal_success=0.1, tracking_emd=5.2),
              two_seeds(tmp_path, "q", 9.0, 1.0, beats_floors=39, goal_success=0.05, tracking_emd=4.9)]
    b = compare_targets.compare(base, base)
    floor = compare_targets.noise_floor(b, [compare_targets.compare(base, c) for c in copies])
    assert floor["walk"] == 2.0 and floor["sum"] == 5.0 and floor["goal"] == pytest.approx(0.05)
    assert floor["EMD"] == pytest.approx(0.2) and floor["tasks > floors"] == 1.0
    # better than the base, but not by more than its copies differ from it: a pass without the floor only
    cand = compare_targets.compare(base, two_seeds(tmp_path, "c", 11.5, 8.0, beats_floors=39, goal_success=0.08,
                                                   tracking_emd=5.25))
    assert compare_targets.rule_failures(b, cand, 95, 95) == ["tasks", "goal", "EMD"]
    assert compare_targets.rule_failures(b, cand, 95, 95, floor) == ["walk", "sum"]
    argv = ["compare_targets.py", "--base", *map(str, base),
            "--candidate", "C", *map(str, two_seeds(tmp_path, "c", 13.0, 8.0, beats_floors=40)),
            "--pushes", "base", "95", "--pushes", "C", "95"]
    monkeypatch.setattr("sys.argv", argv + sum((["--noise", *map(str, c)] for c in copies), []))
    compare_targets.main()
    out = capsys.readouterr().out.splitlines()
    assert out[2].startswith("noise copy 1") and out[3].startswith("noise copy 2")
    assert out[-1].startswith("noise floor") and "walk ±2.0" in out[-1] and "sum ±5" in out[-1]
    assert "rule: passes" in out[4]   # walk +3 and sum +6 beat the floor; goal, EMD and tasks are within it


def test_floors_given_on_the_command_line_widen_the_rule_as_copies_do(tmp_path, capsys, monkeypatch):
    base = two_seeds(tmp_path, "base", 10.0, 5.0, beats_floors=40, goal_success=0.1, tracking_emd=5.0)
    # walk +1.5 and sum +4.5 over the base: a pass without floors, a fail with section 27's walk and sum floors
    cand = two_seeds(tmp_path, "c", 11.5, 8.0, beats_floors=40, goal_success=0.1, tracking_emd=5.0)
    argv = ["compare_targets.py", "--base", *map(str, base), "--candidate", "C", *map(str, cand),
            "--pushes", "base", "95", "--pushes", "C", "95"]
    monkeypatch.setattr("sys.argv", argv)
    compare_targets.main()
    assert "rule: passes" in capsys.readouterr().out
    monkeypatch.setattr("sys.argv", argv + ["--floors", "walk=4.7", "tasks=0.17", "goal=0.005", "EMD=0.11", "sum=16"])
    compare_targets.main()
    out = capsys.readouterr().out.splitlines()
    assert "rule: fails walk, sum" in out[2]
    assert out[-1].startswith("noise floor") and "walk ±4.7" in out[-1] and "sum ±16" in out[-1]
    for bad, message in [("speed=1", "the key must be one of"), ("walk=x", "the value must be a number"),
                         ("sum=nan", "the value must be finite"),
                         ("goal=-1", "the value must be finite and at least 0")]:
        monkeypatch.setattr("sys.argv", argv + ["--floors", bad])
        with pytest.raises(SystemExit):
            compare_targets.main()
        assert f"--floors '{bad}': {message}" in capsys.readouterr().err


def test_the_no_loss_rule_asks_for_no_loss_and_two_gains_beyond_the_floors(tmp_path, capsys, monkeypatch):
    base = two_seeds(tmp_path, "base", 10.0, 5.0, beats_floors=40, goal_success=0.1, tracking_emd=5.0)
    b = compare_targets.compare(base, base)
    floor = {"walk": 4.7, "tasks > floors": 0.17, "goal": 0.005, "EMD": 0.11, "sum": 16.0}

    def cand(name, walk, jump, **measures):
        return compare_targets.compare(base, two_seeds(tmp_path, name, walk, jump, **measures))

    # walk and sum level with the base; goals and tracking better by more than the floors: ships under no-loss only
    level = cand("level", 10.0, 5.0, beats_floors=40, goal_success=0.2, tracking_emd=4.5)
    assert compare_targets.rule_failures(b, level, 95, 95, floor) == ["walk", "sum"]
    assert compare_targets.rule_failures(b, level, 95, 95, floor, rule="no-loss") == []
    # one gain (goals) is not enough; a walk lost beyond its floor fails even with two gains
    one_gain = cand("one", 10.0, 5.0, beats_floors=40, goal_success=0.2, tracking_emd=5.0)
    assert compare_targets.rule_failures(b, one_gain, 95, 95, floor, rule="no-loss") == ["two gains"]
    lost_walk = cand("lost", 5.0, 5.0, beats_floors=40, goal_success=0.2, tracking_emd=4.5)
    assert compare_targets.rule_failures(b, lost_walk, 95, 95, floor, rule="no-loss") == ["walk"]   # sum -5: within 16
    with pytest.raises(ValueError, match="rule 'best'"):
        compare_targets.rule_failures(b, level, 95, 95, floor, rule="best")

    argv = ["compare_targets.py", "--base", *map(str, base), "--candidate", "C",
            *map(str, two_seeds(tmp_path, "c", 10.0, 5.0, beats_floors=40, goal_success=0.2, tracking_emd=4.5)),
            "--pushes", "base", "95", "--pushes", "C", "95",
            "--floors", "walk=4.7", "tasks=0.17", "goal=0.005", "EMD=0.11", "sum=16"]
    monkeypatch.setattr("sys.argv", argv + ["--rule", "no-loss"])
    compare_targets.main()
    assert "rule: passes" in capsys.readouterr().out
    monkeypatch.setattr("sys.argv", argv)
    compare_targets.main()
    assert "rule: fails walk, sum" in capsys.readouterr().out


def test_a_targets_file_with_its_behaviour_table_has_one_model_row(tmp_path):
    data = {"pretrained": {}, "zero": {}, "random": {}, "settings": {}, "behaviours": {"families": {}}}
    assert compare_targets.only_model(tmp_path / "t.json", data) == "pretrained"
