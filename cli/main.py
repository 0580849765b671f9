"""`demo`: the command-line entry point. Each subcommand lives in its own module and only parses
flags and calls a library function; errors become one line on stderr.

A run imports only the module of the command it runs (:data:`COMMANDS`): each one pulls in its part of
the library (mujoco, zarr, mink, torch), and `demo --help` should answer in a fraction of a second."""

from __future__ import annotations

import ast
import enum
import importlib
import importlib.util
import inspect
import os
import re
import shlex
import sys
import traceback
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import typer
import typer.core
import typer.main
from rich.text import Text
from typer._click.exceptions import (  # typer >= 0.29 vendors click (pinned in pyproject)
    BadOptionUsage,
    BadParameter,
    ClickException,
    MissingParameter,
    NoArgsIsHelpError,
    NoSuchOption,
    UsageError,
)

from demo import __version__, interrupts
from demo.cli.output import err_console
from demo.errors import DemoError, one_line, os_error
from demo.verify import NO_VERIFY_ENV

_option_type = typer.core.TyperOption.display_type_rich


def _flag_type(self: typer.core.TyperOption, ctx: Any) -> str | None:
    """The type shown after an option in the help: none for a flag, which takes no value (typer >= 0.29
    shows every flag, --help and --version included, as taking a ``<bool>``; its plain help does not)."""
    if self.is_flag or self.count:
        return None
    return _option_type(self, ctx)


typer.core.TyperOption.display_type_rich = _flag_type  # type: ignore[method-assign]

app = typer.Typer(
    name="demo",
    help="Robot learning from demonstration in MuJoCo: collect, curate, convert, train, eval.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_DEBUG = False
_ARGV: list[str] = []


def invocation() -> str:
    """The command as the user typed it (``demo ...``), for run records."""
    return shlex.join(["demo", *_ARGV])


def _version(value: bool) -> None:
    if value:
        print(f"demo {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
    no_verify: bool = typer.Option(False, "--no-verify", help=(
        "Read stores without checking them (missing chunk files, episode checksums), for a user who knows "
        "the damage; `demo info --check` still checks.")),
) -> None:
    global _DEBUG
    _DEBUG = debug or bool(os.environ.get("DEMO_DEBUG"))
    if no_verify:
        os.environ[NO_VERIFY_ENV] = "1"  # the environment: worker processes inherit it (demo.verify)


# Each top-level command -> the module of demo.cli that defines it (on ``app``, when imported), in the
# order `demo --help` lists them: groups last, where typer puts them.
COMMANDS = {
    "collect": "collect", "info": "info", "quickstart": "quickstart", "export": "export", "import": "import_",
    "view": "view", "curate": "curate", "convert": "convert", "teleop": "teleop", "train": "train", "eval": "eval",
    "serve": "serve", "bench": "bench", "robot": "robot", "irl": "irl",
}


def _register(names: Iterable[str] = COMMANDS) -> None:
    """Define the commands ``names`` on ``app`` (imported here, not at the top: each module imports ``app``)."""
    for name in names:
        importlib.import_module(f"demo.cli.{COMMANDS[name]}")


def _command_group(argv: list[str]) -> typer.core.TyperGroup:
    """The click group that runs ``demo ARGV``, holding what ARGV needs and no more: the command it
    names; for the listing (`demo`, `demo --help`, a mistyped name and its suggestions), a stand-in
    for every command that carries only its help; for `demo --version`, nothing."""
    name = next((arg for arg in argv if not arg.startswith("-")), None)  # demo's own options are all flags
    options = argv[: argv.index(name)] if name else argv
    answer = next((o for o in options if o in ("--help", "--version")), None)  # eager: the first given answers
    if answer is None and name in COMMANDS:
        _register([name])
    group = typer.main.get_command(app)
    assert isinstance(group, typer.core.TyperGroup)  # app has a callback: always a group
    if answer == "--help" or (answer is None and name not in COMMANDS):
        for listed, module in COMMANDS.items():
            group.commands.setdefault(listed, typer.core.TyperCommand(listed, help=_help(module)))
    return group


def _help(module: str) -> str:
    """The help typer shows for the command that ``demo.cli.<module>`` defines, read from the source
    (importing the module would import the library under it, to print one line): the docstring of
    the function under ``@app.command``, or the ``help=`` of the group's ``typer.Typer``."""
    path = Path(importlib.util.find_spec(f"demo.cli.{module}").origin)
    for node in ast.walk(ast.parse(path.read_text(), path)):
        if isinstance(node, ast.FunctionDef) and any(ast.unparse(d).startswith("app.command(") for d in node.decorator_list):
            return ast.get_docstring(node) or ""
        if isinstance(node, ast.Call) and ast.unparse(node.func) == "typer.Typer":
            return inspect.cleandoc(next(ast.literal_eval(k.value) for k in node.keywords if k.arg == "help"))
    raise LookupError(f"{path}: defines no command on app")


def commands() -> dict[str, Any]:
    """Every visible command by its full name (``"bench load"``) -> its click command (tests, docs)."""
    _register()
    found: dict[str, Any] = {}

    def walk(command: Any, path: list[str]) -> None:
        if hasattr(command, "commands"):
            for name, sub in command.commands.items():
                if not sub.hidden:
                    walk(sub, [*path, name])
        else:
            found[" ".join(path)] = command

    walk(typer.main.get_command(app), [])
    return found


def main(argv: list[str] | None = None) -> int:
    """Run ``demo ARGV``; return the exit code. Every failure is one line on stderr,
    ``error: <file>: <problem>`` (``--debug``: the traceback too), whatever the terminal width."""
    global _ARGV
    if argv is None:  # this process is the command: Ctrl-C ends it, within a bounded time
        interrupts.install()
    _ARGV = list(sys.argv[1:] if argv is None else argv)
    verify_setting = os.environ.get(NO_VERIFY_ENV)  # --no-verify lasts one command (main is called in-process too)
    # Library warnings (torch, zarr, h5py) are held back: a failed command prints its one line alone.
    with warnings.catch_warnings(record=True) as caught:
        try:
            rc = _command_group(_ARGV)(args=_ARGV, standalone_mode=False)
        except BaseException as exc:  # noqa: BLE001 - every failure ends here, as one line
            if _DEBUG:
                _show_warnings(caught)
            return _failure(exc)
        finally:
            if verify_setting is None:
                os.environ.pop(NO_VERIFY_ENV, None)
            else:
                os.environ[NO_VERIFY_ENV] = verify_setting
    _show_warnings(caught)
    return rc if isinstance(rc, int) else 0


def _failure(exc: BaseException) -> int:
    """Print ``exc`` as one line (and its traceback with --debug); return the exit code."""
    if isinstance(exc, SystemExit):
        return int(exc.code or 0) if not isinstance(exc.code, str) else 1
    if isinstance(exc, typer.Exit):
        return int(exc.exit_code)
    if isinstance(exc, NoArgsIsHelpError):  # `demo bench`: the help is the answer, not an error
        exc.show()
        return int(exc.exit_code)
    if isinstance(exc, (KeyboardInterrupt, typer.Abort)):
        err_console.print("[bold red]interrupted[/] (finished episodes are kept)")
        return 130
    if _DEBUG and not isinstance(exc, UsageError):
        traceback.print_exception(exc)
    if isinstance(exc, UsageError):
        where, problem = usage_problem(exc)
        _print_error(where, problem)
        return int(exc.exit_code)
    if isinstance(exc, OSError):
        exc = os_error(exc, fallback=_named_path(_ARGV))
    if isinstance(exc, DemoError):
        _print_error(exc.where, exc.problem)
        return exc.exit_code
    if isinstance(exc, ClickException):
        _print_error(None, exc.format_message())
        return int(exc.exit_code)
    _print_error(None, f"{type(exc).__name__}: {exc} (run with --debug for the traceback)")
    return 1


def _print_error(where: str | None, problem: str) -> None:
    if int(os.environ.get("RANK", "0") or 0) != 0:
        return  # data-parallel ranks fail alike: rank 0's line speaks for all (torchrun names the failed ranks)
    # A Text, not markup: a message may hold brackets ("[7]", a file name) that rich would eat.
    text = Text.assemble(("error:", "bold red"), " ", one_line(f"{where}: {problem}" if where else problem))
    err_console.print(text, highlight=False, soft_wrap=True)  # soft_wrap: never broken at the terminal width


def _show_warnings(caught: list[warnings.WarningMessage]) -> None:
    for w in caught:
        err_console.print(Text.assemble(("warning:", "bold yellow"), " ", one_line(f"{w.category.__name__}: {w.message}")),
                          highlight=False, soft_wrap=True)


def usage_problem(exc: UsageError) -> tuple[str, str]:
    """(where, problem) of a command-line mistake: the flag or argument it is about, in our words."""
    command = _command_path(exc.ctx)
    see = f"see {command} --help"
    if isinstance(exc, MissingParameter) and exc.param is not None:
        kind = "argument" if isinstance(exc.param, typer.core.TyperArgument) else "option"
        return _param_name(exc.param), f"missing {kind} ({see})"
    if isinstance(exc, BadParameter) and exc.param is not None:
        message = _sentence(exc.message.removeprefix("Value error, "))  # typer's prefix for a converter's error
        choices = _enum_choices(exc.param)
        given = re.search(r"('.*') is not one of", message)
        if choices and given:
            message = f"{given.group(1)} is not one of {', '.join(choices)}"
        return _param_name(exc.param), message
    if isinstance(exc, NoSuchOption):
        near = f"; did you mean {' or '.join(sorted(exc.possibilities))}?" if exc.possibilities else ""
        return exc.option_name, f"no such option of {command}{near} ({see})"
    if isinstance(exc, BadOptionUsage):
        return exc.option_name, _sentence(exc.message).replace(f"Option '{exc.option_name}' ", "")
    return command, f"{_sentence(exc.message)} ({see})"


def _sentence(message: str) -> str:
    text = one_line(message).rstrip(".")
    return text[:1].lower() + text[1:] if text[:1].isupper() and not text[1:2].isupper() else text


def _param_name(param: Any) -> str:
    if isinstance(param, typer.core.TyperArgument):
        return str(param.metavar or param.name).upper()
    longs = [o for o in param.opts if o.startswith("--")]
    return (longs or list(param.opts) or [str(param.name)])[0]


def _enum_choices(param: Any) -> list[str]:
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return [str(e.value) for e in annotation]
    return []


def _command_path(ctx: Any) -> str:
    names = []
    while ctx is not None:
        names.append(ctx.info_name or "")
        ctx = ctx.parent
    return " ".join(["demo", *reversed(names[:-1])]) if names else "demo"


def _named_path(argv: list[str]) -> str | None:
    """What an OS error without a file name is about: the command's ``--out``, else its first
    argument that is an existing path (the store or run it reads or edits in place)."""
    for i, arg in enumerate(argv):
        if arg in ("--out", "-o") and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--out="):
            return arg[len("--out="):]
    existing = [a for a in argv if not a.startswith("-") and os.path.exists(a)]
    return existing[0] if existing else None


if __name__ == "__main__":
    from demo.cli.main import main as _main  # the registered app lives in the imported module

    sys.exit(_main())
