"""GraphedStep: one whole training step captured in a CUDA graph, then replayed.

On an H100 a small FB-CPR update took 22-29 ms for 0.2-7 ms of matmuls (docs/benchmarks.md): its ~300
kernels and the Python that launches them set the time. Captured once, the whole step (losses, backward, the
optimisers' steps, Polyak) replays with one launch. The inputs are copied into static tensors that the graph reads,
and the outputs are the graph's own tensors, overwritten by every replay.

What the step must do to be captured (the capture raises otherwise, and the step then runs eagerly with a
warning): no host synchronisation (no `.item()`, no boolean-mask indexing, no device tensors built from Python
lists), the same shapes on every call, optimisers built with `capturable=True`, and random draws only from the
default CUDA generator or from the generators handed to `GraphedStep`.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

Step = Callable[[dict[str, Tensor]], dict[str, Tensor]]


class GraphedStep:
    """Calls `step(inputs)` eagerly `warmup` times on a side stream, captures it on the next call, and replays the
    capture from then on. On a device other than CUDA it only calls `step`."""

    def __init__(self, step: Step, device: torch.device, generators: Sequence[torch.Generator] = (),
                 warmup: int = 3) -> None:
        self.step, self.generators, self.warmup = step, tuple(generators), int(warmup)
        self.enabled = torch.device(device).type == "cuda"
        self.calls = 0
        self.graph: torch.cuda.CUDAGraph | None = None
        self.static_inputs: dict[str, Tensor] = {}
        self.static_outputs: dict[str, Tensor] = {}
        self.failure: str | None = None  # why capture failed, once it has

    @property
    def captured(self) -> bool:
        return self.graph is not None

    def __call__(self, inputs: dict[str, Tensor]) -> dict[str, Tensor]:
        if not self.enabled or self.failure is not None:
            return self.step(inputs)
        if self.graph is None:
            self.calls += 1
            if self.calls <= self.warmup:
                return self._side_stream(inputs)
            if not self._capture(inputs):
                return self.step(inputs)
        for key, value in inputs.items():
            self.static_inputs[key].copy_(value)
        assert self.graph is not None  # set by the successful _capture above
        self.graph.replay()
        return self.static_outputs

    def _side_stream(self, inputs: dict[str, Tensor]) -> dict[str, Tensor]:
        """An eager call on a side stream, as PyTorch asks of the calls before a capture (lazy initialisations,
        optimiser state and library workspaces then exist before the capture begins)."""
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            out = self.step(inputs)
        torch.cuda.current_stream().wait_stream(side)
        return out

    def _capture(self, inputs: dict[str, Tensor]) -> bool:
        """Capture one step on static copies of `inputs` (the capture runs nothing; the replay that follows does)."""
        self.static_inputs = {k: v.detach().clone() for k, v in inputs.items()}
        graph = torch.cuda.CUDAGraph()
        try:
            for generator in self.generators:
                graph.register_generator_state(generator)
            with torch.cuda.graph(graph):
                self.static_outputs = self.step(self.static_inputs)
        except (RuntimeError, AttributeError) as e:  # an op that cannot be captured; an older torch
            self.failure = str(e).splitlines()[0] if str(e) else type(e).__name__
            self.static_inputs, self.static_outputs = {}, {}
            torch.cuda.synchronize()
            warnings.warn(f"agent.cuda_graph: capturing the update failed, so it runs eagerly ({self.failure})",
                          RuntimeWarning, stacklevel=3)
            return False
        self.graph = graph
        return True


def make_capturable(optimizer: torch.optim.Optimizer) -> None:
    """Ready an optimiser whose state was loaded from a checkpoint for capture: `capturable` on in every group, and
    each parameter's step counter on its parameter's device (a checkpoint saved by an eager run holds them on the
    CPU, and loading keeps the saved groups' settings)."""
    for group in optimizer.param_groups:
        group["capturable"] = True
        for p in group["params"]:
            state = optimizer.state.get(p, {})
            if "step" in state:
                state["step"] = state["step"].to(p.device, torch.float32)
