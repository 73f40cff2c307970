"""A built wheel must contain every sub-package: pyproject lists them by hand (cli/ maps onto fbcpr.cli, configs/
onto fbcpr.configs)."""
import tomllib
from importlib import resources
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAPPED = {"cli": "fbcpr.cli", "configs": "fbcpr.configs"}


def test_every_package_directory_is_declared():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = set()
    for top in ("fbcpr", "humanoid_env", "motions", *MAPPED):
        for init in (ROOT / top).rglob("__init__.py"):
            parts = init.parent.relative_to(ROOT).parts
            found.add(".".join((MAPPED.get(parts[0], parts[0]), *parts[1:])))
    declared = set(cfg["packages"])
    assert found == declared, f"missing from pyproject: {found - declared}; stale: {declared - found}"
    assert cfg["package-dir"] == {v: k for k, v in MAPPED.items()}


def test_shipped_configs_are_importable_resources():
    names = {p.name for p in resources.files("fbcpr.configs").iterdir() if p.name.endswith(".yaml")}
    assert {"quickstart.yaml", "small.yaml", "paper-S.yaml", "paper-M.yaml"} <= names
