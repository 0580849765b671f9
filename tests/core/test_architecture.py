"""The package layering of docs/architecture.md, enforced: a module imports only from its own package, from
a lower layer, or from the foundation; packages in one layer do not import each other.

Every import counts, at the top of a module or inside a function (an import deferred to keep torch out of
`demo --help` is still a dependency), and so does a module named in an ``importlib.import_module`` string
literal or a ``"module:function"`` registry entry.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# Bottom to top. A package may import from any layer below its own; packages sharing a layer are independent.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "interrupts", "jsonio", "seeds", "progress", "figures", "executor", "verify", "__init__"),  # foundation
    ("store",),
    ("sim",),
    ("collect", "curate", "convert", "interop"),  # the pipeline's stages, over stores and the simulator
    ("policies",),  # networks, their inputs and outputs, saved policies
    ("evaluation", "gym"),  # rolling a policy out; the tasks as Gymnasium environments
    ("training",),  # the trainer core
    ("imitation", "rl"),  # the algorithms
    ("algorithms",),  # every algorithm by name
    ("view", "deploy"),  # browser front ends: replay, live teleoperation; a policy served to a robot
    ("bench",),  # performance benchmarks
    ("experiments", "quickstart"),  # the training experiments; the whole pipeline on defaults
    ("cli",),
    ("__main__",),  # python -m demo
)
LAYER_OF = {name: i for i, layer in enumerate(LAYERS) for name in layer}
FOUNDATION = set(LAYERS[0])
EXCEPTIONS: set[tuple[str, str]] = set()  # (importer, imported) pairs allowed against the layering: none today


def package_of(path: Path) -> str:
    rel = path.relative_to(ROOT)
    return rel.parts[0].removesuffix(".py")


def imported_packages(source: str) -> list[tuple[str, int]]:
    """(top-level demo package, line) of every import in ``source``, static or by name."""
    found: list[tuple[str, int]] = []
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "demo":
                found += [(alias.name, node.lineno) for alias in node.names]
            elif node.module.startswith("demo."):
                found.append((node.module.split(".")[1], node.lineno))
        elif isinstance(node, ast.Import):
            found += [(a.name.split(".")[1], node.lineno) for a in node.names if a.name.startswith("demo.")]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            match = re.fullmatch(r"demo\.([a-z_]+)(\.[a-z_.]+)?(:[A-Za-z_]+)?", node.value)
            if match and (match.group(3) or match.group(2)):
                found.append((match.group(1), node.lineno))
    return found


def violations(files: dict[str, str]) -> list[str]:
    """Every import against the layering in ``files`` (path relative to the package root -> source)."""
    problems = []
    for rel, source in sorted(files.items()):
        here = Path(rel).parts[0].removesuffix(".py")
        if here not in LAYER_OF:
            problems.append(f"{rel}: package {here!r} is in no layer (add it to LAYERS and docs/architecture.md)")
            continue
        for target, line in imported_packages(source):
            if target == here or target in FOUNDATION or target == "__version__":
                continue
            if target not in LAYER_OF:
                problems.append(f"{rel}:{line}: imports demo.{target}, which is in no layer")
            elif LAYER_OF[target] >= LAYER_OF[here] and (here, target) not in EXCEPTIONS:
                kind = "a sibling" if LAYER_OF[target] == LAYER_OF[here] else "a higher layer"
                problems.append(f"{rel}:{line}: {here} imports demo.{target}, {kind}")
    return problems


def library_files() -> dict[str, str]:
    skip = {"tests", "tools", "docs", "build"}
    # A virtual environment in the root (docs/environments.md's gym-aloha venv, `aloha/`) is no part of the library.
    skip |= {p.parent.name for p in ROOT.glob("*/pyvenv.cfg")}
    return {str(p.relative_to(ROOT)): p.read_text() for p in ROOT.rglob("*.py")
            if p.relative_to(ROOT).parts[0] not in skip and not p.relative_to(ROOT).parts[0].startswith(".")}


def test_the_library_follows_its_layering() -> None:
    problems = violations(library_files())
    assert not problems, "imports against docs/architecture.md's layering:\n" + "\n".join(problems)


def test_every_package_is_in_a_layer() -> None:
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} | {p.stem for p in ROOT.glob("*.py")}
    missing = sorted(packages - set(LAYER_OF) - {"setup", "conftest"})
    assert not missing, f"packages in no layer: {missing}"


@pytest.mark.parametrize("rel, source, expected", [
    ("store/reader.py", "from demo.training.trainer import TrainingRun\n", "store imports demo.training, a higher layer"),
    ("sim/env.py", "def f():\n    from demo.collect.scripted import CollectConfig\n", "sim imports demo.collect, a higher layer"),
    ("collect/x.py", "import demo.curate.curate\n", "collect imports demo.curate, a sibling"),
    ("policies/x.py", "PLUGIN = 'demo.imitation.bc:train'\n", "policies imports demo.imitation, a higher layer"),
    ("training/x.py", "importlib.import_module('demo.rl.ppo')\n", "training imports demo.rl, a higher layer"),
])
def test_an_upward_import_is_caught(rel: str, source: str, expected: str) -> None:
    """A deliberately added upward import (at the top, in a function, or by name) fails the check."""
    problems = violations({rel: source})
    assert len(problems) == 1 and expected in problems[0], problems


def test_downward_and_foundation_imports_pass() -> None:
    assert violations({"training/x.py": "from demo.policies.policy import Policy\nfrom demo.errors import DemoError\n"}) == []
    assert violations({"cli/x.py": "from demo.algorithms import train\n"}) == []
