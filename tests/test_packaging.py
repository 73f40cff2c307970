"""A built wheel must contain every sub-package: setuptools finds packages by their `__init__.py`, so a folder of
modules without one would be left out of the wheel."""
import tomllib
from importlib import resources
from pathlib import Path

from setuptools import find_packages

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_directory_is_found():
    include = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]["include"]
    found = set(find_packages(str(ROOT), include=include))
    with_modules = {".".join(p.parent.relative_to(ROOT).parts) for top in ("fbcpr", "humanoid_env", "motions")
                    for p in (ROOT / top).rglob("*.py")}
    assert with_modules <= found, f"folders of modules setuptools would leave out: {with_modules - found}"
    assert not any(name.startswith(("lab", "tests", "benchmarks")) for name in found)


def test_shipped_configs_are_importable_resources():
    names = {p.name for p in resources.files("fbcpr.configs").iterdir() if p.name.endswith(".yaml")}
    assert {"quickstart.yaml", "small.yaml", "paper-S.yaml", "paper-M.yaml"} <= names
