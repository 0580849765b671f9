"""`demo --help`, `demo bench --help` and `demo info STORE` start without importing torch, and the
commands that only list or read import no more of the library than they use (issue #41: under 1 s).

Each command runs in a fresh interpreter (``sys.modules`` of this process holds torch already), through
:func:`demo.cli.main.main`; the child reports whether torch was imported and, if so, the import chain
that first asked for it, which of the slow libraries were imported, and what the command printed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from demo.cli.main import main

CHILD = """
import json, sys, traceback

class FirstTorchImport:
    chain = None

    def find_spec(self, name, path=None, target=None):
        if name == "torch" and FirstTorchImport.chain is None:
            FirstTorchImport.chain = [f"{f.filename}:{f.lineno}" for f in traceback.extract_stack()[:-1]
                                      if not f.filename.startswith("<")]
        return None

sys.meta_path.insert(0, FirstTorchImport())
from demo.cli.main import commands, main

if REGISTER_ALL:
    commands()
try:
    rc = main(sys.argv[1:])
except SystemExit as exc:
    rc = exc.code
print(json.dumps({"rc": rc, "torch": "torch" in sys.modules, "chain": FirstTorchImport.chain,
                  "imported": [m for m in SLOW if m in sys.modules]}))
"""
# What a command that only lists or reads should not import for nothing (import time on a quiet machine):
# torch (1-2 s), mink (0.2-0.5 s: the IK of experts), zarr (0.2 s: stores), av (0.15 s: videos), mujoco.
SLOW = ("torch", "mink", "zarr", "av", "mujoco")


def startup(tmp_path: Path, *argv: str, register_all: bool = False) -> dict:
    """``demo ARGV`` in a fresh interpreter (after registering every command, if ``register_all``): its
    exit code, whether torch was imported and how, which of SLOW were imported, and its stdout."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "COLUMNS": "120"}
    code = f"REGISTER_ALL = {register_all}\nSLOW = {SLOW}\n{CHILD}"
    child = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=180,
                           cwd=tmp_path, env=env)
    assert child.returncode == 0, child.stderr
    *printed, last = child.stdout.strip("\n").splitlines()
    return {**json.loads(last), "stdout": printed}


@pytest.fixture(scope="module")
def tiny_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("startup") / "reach.zarr"
    assert main(["collect", "--task", "reach", "--episodes", "1", "--seed", "0", "--out", str(out), "--workers", "0"]) == 0
    return out


@pytest.mark.parametrize("argv", [["--help"], ["bench", "--help"]], ids=["demo --help", "demo bench --help"])
def test_help_imports_no_torch(tmp_path: Path, argv: list[str]) -> None:
    result = startup(tmp_path, *argv)
    assert result["rc"] == 0
    assert not result["torch"], "torch imported by:\n" + "\n".join(result["chain"] or [])


def test_info_imports_neither_torch_nor_mink(tmp_path: Path, tiny_store: Path) -> None:
    result = startup(tmp_path, "info", str(tiny_store))
    assert result["rc"] == 0
    assert not result["torch"], "torch imported by:\n" + "\n".join(result["chain"] or [])
    assert "mink" not in result["imported"]  # describing a robot solves no IK


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["colect"]], ids=["--help", "--version", "a typo"])
def test_the_listing_imports_none_of_the_library(tmp_path: Path, argv: list[str]) -> None:
    """Before, `demo --help` imported every command's module, and with them mujoco, zarr and mink: a
    second before the first line. The listing now reads each command's help from its source."""
    result = startup(tmp_path, *argv)
    assert result["imported"] == []


def test_the_listing_is_the_commands_own(tmp_path: Path) -> None:
    """Every command `commands()` registers is listed by `demo --help`, in the same place, with the same help."""
    listed = startup(tmp_path, "--help")
    registered = startup(tmp_path, "--help", register_all=True)
    assert listed["stdout"] == registered["stdout"]
    assert any(line.startswith("│ irl ") for line in listed["stdout"])  # the last one: the listing is not empty


def test_view_imports_no_ik_and_no_video(tmp_path: Path) -> None:
    """`demo view` prints its address in under a second: it needs mujoco, zarr and viser, not mink or av."""
    result = startup(tmp_path, "view", "--help")
    assert result["rc"] == 0
    assert not {"torch", "mink", "av"} & set(result["imported"])
