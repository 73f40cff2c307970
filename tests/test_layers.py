"""The package's structure: no import cycle, every import points down the layers, and the registry's entries
exist. Imports inside functions and under TYPE_CHECKING count: a cycle hidden in a function is still a cycle."""
import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("fbcpr", "humanoid_env", "motions")
#: fbcpr's sub-packages, lowest first: each may import only its own layer and those before it (`configs` is data).
LAYERS = ("configs", "core", "nn", "metrics", "envs", "rewards", "methods", "eval", "inference", "train", "apps", "cli")
#: Modules of the package root, above every layer (the lazy `fbcpr.BFM` and `python -m fbcpr`).
TOP = ("fbcpr", "fbcpr.__main__")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package modules `name` imports anywhere in its source (a `from a import b` of a module b counts b)."""
    found = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for target in targets:
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


MODULES = _modules()
GRAPH = {name: _imports(name, path, MODULES) for name, path in MODULES.items()}


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, out, counter = {}, {}, [], set(), [], [0]
    for root in GRAPH:
        if root in index:
            continue
        work = [(root, iter(sorted(GRAPH[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(GRAPH[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def _layer(name: str) -> int:
    if name in TOP:
        return len(LAYERS)
    return LAYERS.index(name.split(".")[1])


def test_no_import_cycle():
    assert _cycles() == []


def test_the_cycle_check_finds_a_cycle():
    GRAPH["fbcpr.core.errors"].add("fbcpr.core.config")
    try:
        assert any("fbcpr.core.errors" in c for c in _cycles())
    finally:
        GRAPH["fbcpr.core.errors"].discard("fbcpr.core.config")


def test_every_fbcpr_module_sits_in_a_layer():
    strays = [n for n in MODULES if n.startswith("fbcpr") and n not in TOP and n.split(".")[1] not in LAYERS]
    assert strays == [], f"add these to a layer (tests/test_layers.py LAYERS): {strays}"


def test_imports_point_down_the_layers():
    up = [f"{a} -> {b}" for a in GRAPH if a.startswith("fbcpr.") and a not in TOP
          for b in GRAPH[a] if b.startswith("fbcpr.") and _layer(b) > _layer(a)]
    assert up == []


def test_env_and_motions_never_import_the_learner():
    """Data flows one way: motions and the env know nothing of fbcpr, and the env nothing of motion files."""
    bad = [f"{a} -> {b}" for a in GRAPH if not a.startswith("fbcpr") for b in GRAPH[a]
           if b.startswith("fbcpr") or (a.startswith("humanoid_env") and b.startswith("motions"))]
    assert bad == []


def test_few_modules_flat_in_the_package_root():
    flat = sorted(p.name for p in (ROOT / "fbcpr").glob("*.py"))
    assert len(flat) < 8, flat


@pytest.mark.parametrize("entry", ["methods", "rewards", "envs", "offline"])
def test_registry_entries_resolve(entry):
    from fbcpr.core import registry

    paths = {"methods": [p for m in registry.METHODS.values() for p in (m.config_path, m.agent_path, m.model_path)],
             "rewards": [p for r in registry.IMITATION_REWARDS.values() for p in (r.reward_path, r.config_path)],
             "envs": [p for e in registry.ENVS.values() for p in (e.make_path, e.observer_path)],
             "offline": [*registry.OFFLINE_MODELS.values(), registry.LATENT_ACTIONS]}[entry]
    for path in paths:
        module, attr = path.split(":")
        assert hasattr(importlib.import_module(module), attr), path
