"""`demo --help`, `demo bench --help` and `demo info STORE` start without importing torch.

Each command runs in a fresh interpreter (``sys.modules`` of this process holds torch already), through
:func:`demo.cli.main.main`; the child reports whether torch was imported and, if so, the import chain
that first asked for it.
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
from demo.cli.main import main

try:
    rc = main(sys.argv[1:])
except SystemExit as exc:
    rc = exc.code
print(json.dumps({"rc": rc, "torch": "torch" in sys.modules, "chain": FirstTorchImport.chain}))
"""


def startup(tmp_path: Path, *argv: str) -> dict:
    """``demo ARGV`` in a fresh interpreter: its exit code, whether torch was imported, and how."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    child = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True, timeout=180,
                           cwd=tmp_path, env=env)
    assert child.returncode == 0, child.stderr
    return json.loads(child.stdout.strip().splitlines()[-1])


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


def test_info_imports_no_torch(tmp_path: Path, tiny_store: Path) -> None:
    result = startup(tmp_path, "info", str(tiny_store))
    assert result["rc"] == 0
    assert not result["torch"], "torch imported by:\n" + "\n".join(result["chain"] or [])
