"""benchmarks/learner_selftest.py, which a GPU run executes before training: its CPU path runs every check, finds
eager twins equal and bf16 close, and a departing twin fails it."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import torch

torch.set_num_threads(1)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
learner_selftest = importlib.import_module("learner_selftest")


def test_cpu_selftest_passes_with_every_check():
    lines: list[str] = []
    failures = []
    for check in (learner_selftest.graph_twins, learner_selftest.bf16_agreement):
        got, line = check("tiny", "cpu", 2)
        failures += got
        lines.append(line)
    assert failures == []
    assert lines[0].startswith("graph tiny: eager (not CUDA); after 2 updates")
    assert lines[0].count("0.00e+00") == 9  # every pair of eager twins agrees exactly on the CPU
    cosines = [float(part.split()[1]) for part in lines[1].split("(next batch's) ")[1].split("; ")[0].split(", ")]
    assert len(cosines) == 5 and all(c >= learner_selftest.MIN_COSINE for c in cosines)
    assert learner_selftest.selftest("cpu", ("tiny",), updates=1) == []


def test_a_graph_that_departs_fails(monkeypatch):
    """A 'graphed' agent from another seed stands in for a graph that replays the wrong thing."""
    make = learner_selftest.make

    def departing(preset, device, compile_, bf16=False, regulariser="discriminator", graph=False, data_seed=0):
        agent, batch, windows = make(preset, device, compile_, bf16, regulariser, graph, data_seed)
        if graph:
            torch.manual_seed(7)
            for p in agent.model.parameters():
                p.data.add_(0.05 * torch.randn_like(p))
        return agent, batch, windows

    monkeypatch.setattr(learner_selftest, "make", departing)
    failures, _ = learner_selftest.graph_twins("tiny", "cpu", 2)
    assert len(failures) == 1 and "departs from the eager one with the same Adam" in failures[0]
