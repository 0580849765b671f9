"""The CLI shell: subcommands listed, version, one-line errors, tracebacks only with --debug."""

from __future__ import annotations

import subprocess
import sys

import pytest

from demo import __version__
from demo.cli.main import app, main

SUBCOMMANDS = ["collect", "curate", "convert", "train", "eval", "info", "export", "import", "view", "bench", "quickstart"]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "demo", *args], capture_output=True, text=True, timeout=120)


def test_help_lists_every_subcommand() -> None:
    out = run_cli("--help")
    assert out.returncode == 0
    for name in SUBCOMMANDS:
        assert f" {name} " in out.stdout, name


def test_version(capsys: pytest.CaptureFixture) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"demo {__version__}"


def test_usage_error_exits_2() -> None:
    out = run_cli("info")
    assert out.returncode == 2 and "Missing argument" in out.stderr


@app.command("explode", hidden=True)
def _explode() -> None:
    raise ValueError("kaput")


def test_unexpected_error_is_one_line_without_debug(capsys: pytest.CaptureFixture) -> None:
    assert main(["explode"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == ["error: ValueError: kaput (run with --debug for the traceback)"]
    assert main(["--debug", "explode"]) == 1
    assert "Traceback" in capsys.readouterr().err
