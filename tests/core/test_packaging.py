"""Packaging: every sub-package folder is installed under `demo.` (not as a generic top-level name)."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_subpackage_is_listed_in_pyproject() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert config["package-dir"] == {"demo": "."}
    listed = set(config["packages"])
    found = {
        "demo." + ".".join(p.parent.relative_to(ROOT).parts) if p.parent != ROOT else "demo"
        for p in ROOT.rglob("__init__.py")
        if not {".venv", "tests", "build", ".git"} & set(p.relative_to(ROOT).parts)
    }
    assert found - listed == set(), "add these to [tool.setuptools] packages"
    assert listed - found == set(), "listed but missing"


def test_demo_imports_from_the_checkout() -> None:
    import demo
    import demo.collect
    import demo.store

    assert Path(demo.__file__).resolve().parent == ROOT
    assert Path(demo.store.__file__).resolve().parent == ROOT / "store"
