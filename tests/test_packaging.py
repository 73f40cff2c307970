"""A built wheel must contain every sub-package: pyproject lists them by hand (cli/ maps onto fbcpr.cli)."""
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _declared() -> set[str]:
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    return set(cfg["packages"]), cfg["package-dir"]


def test_every_package_directory_is_declared():
    declared, package_dir = _declared()
    found = set()
    for top in ("fbcpr", "humanoid_env", "motions", "cli"):
        for init in (ROOT / top).rglob("__init__.py"):
            parts = init.parent.relative_to(ROOT).parts
            name = ".".join(parts)
            found.add("fbcpr.cli" + name[3:] if parts[0] == "cli" else name)
    assert found == declared, f"missing from pyproject: {found - declared}; stale: {declared - found}"
    assert package_dir == {"fbcpr.cli": "cli"}
