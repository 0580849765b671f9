"""The CLI shell: subcommands listed, version, one-line errors, tracebacks only with --debug, and one
style for every command (positional names, defaults in the help, plain flags)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from demo import __version__
from demo.cli.main import app, commands, main

SUBCOMMANDS = ["collect", "curate", "convert", "train", "eval", "info", "export", "import", "view", "bench", "quickstart"]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "demo", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_help_lists_every_subcommand() -> None:
    out = run_cli("--help")
    assert out.returncode == 0
    for name in SUBCOMMANDS:
        assert f" {name} " in out.stdout, name


def test_version(capsys: pytest.CaptureFixture) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"demo {__version__}"


@pytest.mark.slow
def test_usage_error_exits_2() -> None:
    out = run_cli("info")
    assert out.returncode == 2 and out.stderr == "error: STORE: missing argument (see demo info --help)\n"


@app.command("explode", hidden=True)
def _explode() -> None:
    raise ValueError("kaput")


def test_unexpected_error_is_one_line_without_debug(capsys: pytest.CaptureFixture) -> None:
    assert main(["explode"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == ["error: ValueError: kaput (run with --debug for the traceback)"]
    assert main(["--debug", "explode"]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_one_style_for_every_command() -> None:
    import typer.core

    found = commands()
    assert {"collect", "eval", "bench load", "bench infer"} <= set(found)
    problems = []
    for name, command in found.items():
        for p in command.params:
            where = f"demo {name} {p.name}"
            if isinstance(p, typer.core.TyperArgument):
                # TOML: a robot config (demo robot check); SUITE: a public benchmark's task set (demo bench suite);
                # MJCF: a robot's model file (demo robot init)
                if p.metavar not in ("STORE", "RUN", "DATASET", "TOML", "SUITE", "MJCF"):
                    problems.append(f"{where}: a store is STORE, a run RUN, a robot config TOML, a robot model MJCF")
                continue
            if p.name == "help":
                continue
            if any(o.startswith("--no-no") for o in p.secondary_opts):
                problems.append(f"{where}: --no-no")
            if ("--overwrite" in p.opts or "--append" in p.opts) and (not p.is_flag or p.secondary_opts):
                problems.append(f"{where}: not a plain flag")
            if "--json" in p.opts and p.metavar != "FILE|-":
                problems.append(f"{where}: not --json FILE|-")
            if "--episodes" in p.opts and p.type_descriptor.annotation is not int:
                problems.append(f"{where}: --episodes is a count; a subset is --mask NAME")
            if "--mask" in p.opts and p.metavar != "NAME":
                problems.append(f"{where}: not --mask NAME")
            is_plain_flag = p.is_flag and not p.secondary_opts
            shown = p.show_default is not False and (p.default not in (None, []) or isinstance(p.show_default, str))
            if not (is_plain_flag or p.required or shown):
                problems.append(f"{where}: the help does not say what the default is")
    assert problems == []



def test_flags_show_no_value_type_in_the_help(capsys: pytest.CaptureFixture[str]) -> None:
    """Before, every flag read `<bool>` in the help (`--version <bool>` included), as if it took a value."""
    for argv in (["--help"], ["collect", "--help"]):
        capsys.readouterr()
        assert main(argv) == 0
        shown = capsys.readouterr().out
        assert "--version" in shown or "--append" in shown
        assert "<bool>" not in shown, shown
    assert "<int>" in shown  # an option that takes a value still shows its type


def test_help_keeps_brackets_that_rich_would_read_as_markup() -> None:
    """`--executor`'s help names the extra to install, `.[ray]`, which rich markup would swallow."""
    shown = subprocess.run([sys.executable, "-m", "demo", "eval", "--help"], capture_output=True, text=True,
                           env={**os.environ, "COLUMNS": "300"}).stdout
    assert "pip install -e '.[ray]'" in shown
