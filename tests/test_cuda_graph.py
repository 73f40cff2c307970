"""agent.cuda_graph: the update's captured part waits on no host, the option's errors, and its CPU behaviour.

Capture itself needs a CUDA device (benchmarks/update_speed.py --graph checks it on a lease); what can be checked
here is what capture requires of the step: no op that synchronises with the host.
"""
import copy
import importlib.util
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from fbcpr.core.config import config_from_dict
from fbcpr.core.errors import ConfigError
from fbcpr.nn.cuda_graph import GraphedStep, make_capturable
from fbcpr.methods.fb_cpr import losses
from test_fbcpr_agent import make_agent, make_batch

torch.set_num_threads(1)

#: aten ops that make the host wait for the device, which a CUDA graph capture refuses.
HOST_SYNCS = {"_local_scalar_dense", "item", "nonzero", "masked_select", "_linalg_check_errors", "equal",
              "is_nonzero", "unique", "_unique2"}


class OpRecorder(TorchDispatchMode):
    """Names of the aten ops that run inside it."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: set[str] = set()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.ops.add(func.overloadpacket.__name__)
        return func(*args, **(kwargs or {}))


def syncs_of(fn) -> set[str]:
    with OpRecorder() as rec:
        fn()
    return rec.ops & HOST_SYNCS


@pytest.mark.parametrize("options", [{}, {"action_penalty": 0.5}, {"anchor_actor": 2.0},
                                     {"freeze_backward": True, "anchor_actor": 2.0}])
def test_the_captured_step_never_waits_on_the_host(options):
    agent = make_agent(**options)
    batch, windows = make_batch(agent)
    inputs = agent._inputs(batch, windows)
    agent._train_step(inputs)  # the first step creates Adam's state, as the warm-up calls do before a capture
    # the losses, backward and Polyak; Adam's step is PyTorch's own capturable path on CUDA (on the CPU, where it
    # cannot be capturable, it reads its step counter with .item())
    assert syncs_of(lambda: (agent._backward(inputs), agent.soft_update())) == set()


def test_the_recorder_sees_a_host_sync():
    """The check above can fail: a Cholesky with its error check (as the implicit reward had it) is caught."""
    cov = torch.eye(4) * 2.0
    assert "_linalg_check_errors" in syncs_of(lambda: torch.linalg.cholesky(cov))
    assert syncs_of(lambda: torch.linalg.cholesky_ex(cov)) == set()
    b, z = torch.randn(16, 4), torch.randn(16, 4)
    assert syncs_of(lambda: losses.implicit_reward(b, z)) == set()


def test_cpu_runs_the_update_as_without_the_option():
    plain, graphed = make_agent(), make_agent(cuda_graph=True)
    assert not graphed.graphed and graphed._step == graphed._train_step
    assert all(not g["capturable"] for opt in graphed.optimizers.values() for g in opt.param_groups)
    for seed in range(3):
        batch, windows = make_batch(plain, seed=seed)
        assert plain.update(batch, windows) == graphed.update(batch, windows)
    for a, b in zip(plain.model.parameters(), graphed.model.parameters()):
        assert torch.equal(a, b)


def test_graphed_step_off_cuda_calls_the_step():
    calls = []
    step = GraphedStep(lambda inputs: calls.append(inputs) or {"y": inputs["x"] * 2}, torch.device("cpu"))
    x = torch.arange(3.0)
    assert torch.equal(step({"x": x})["y"], x * 2)
    assert len(calls) == 1 and not step.enabled and not step.captured


def test_make_capturable_moves_step_counters_and_sets_the_flag():
    agent = make_agent()
    batch, windows = make_batch(agent)
    agent.update(batch, windows)
    opt = copy.deepcopy(agent.optimizers["actor"])
    make_capturable(opt)
    assert all(g["capturable"] for g in opt.param_groups)
    steps = [s["step"] for s in opt.state.values()]
    assert steps and all(s.dtype == torch.float32 and float(s) == 1.0 for s in steps)


@pytest.mark.parametrize("agent, message", [
    ({"cuda_graph": True, "compile": True}, "agent.cuda_graph: choose one"),
    ({"cuda_graph": True, "regulariser": "near"}, "agent.cuda_graph: needs regulariser: discriminator"),
])
def test_cuda_graph_refuses_what_it_cannot_capture(agent, message):
    with pytest.raises(ConfigError, match=message):
        config_from_dict({"model": {"preset": "tiny", "obs_dim": 6, "action_dim": 3}, "agent": agent})


def test_the_lease_agreement_check_runs_and_finds_eager_twins_equal():
    """benchmarks/update_speed.py --graph runs this first on a lease; off CUDA both twins are eager and agree."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "update_speed.py"
    spec = importlib.util.spec_from_file_location("update_speed", path)
    update_speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(update_speed)
    line = update_speed.graph_agreement("tiny", "cpu", updates=2)
    assert line.startswith("tiny: eager (not CUDA); agree; after 2 updates")
    assert line.count("0.00e+00") == 9
    assert "graphed vs eager with the graph's capturable Adam: 0.00e+00, 0.00e+00, 0.00e+00;" in line
    growth = line.split("per update, the metric that differs most: ")[1].split(", ")
    assert [g.split(":")[0] for g in growth] == ["1", "2"] and all(g.endswith(" 0.0e+00") for g in growth)
