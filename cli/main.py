"""`demo`: the command-line entry point. Each subcommand lives in its own module and only parses
flags and calls a library function; errors become one line on stderr."""

from __future__ import annotations

import os
import sys
import traceback
from typing import Any

import typer
import typer.main

from demo import __version__
from demo.cli.output import err_console
from demo.errors import DemoError

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
    import shlex

    return shlex.join(["demo", *_ARGV])


def _version(value: bool) -> None:
    if value:
        print(f"demo {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors."),
) -> None:
    global _DEBUG
    _DEBUG = debug or bool(os.environ.get("DEMO_DEBUG"))


def _register() -> None:
    # Imported here so `demo --help` stays one import deep per subcommand module.
    from demo.cli import commands  # noqa: F401


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
    global _ARGV
    _ARGV = list(sys.argv[1:] if argv is None else argv)
    _register()
    try:
        rc = app(args=argv, standalone_mode=False)
    except DemoError as exc:
        if _DEBUG:
            traceback.print_exc()
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return exc.exit_code
    except KeyboardInterrupt:
        err_console.print("[bold red]interrupted[/] (finished episodes are kept)")
        return 130
    except SystemExit as exc:
        return int(exc.code or 0)
    except typer.Exit as exc:
        return int(exc.exit_code)
    except typer.Abort:
        err_console.print("[bold red]aborted[/]")
        return 130
    except Exception as exc:  # usage errors (they know how to show themselves) and the unexpected
        if hasattr(exc, "show") and hasattr(exc, "exit_code"):
            exc.show()
            return int(exc.exit_code)
        if _DEBUG:
            traceback.print_exc()
        err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {exc} (run with --debug for the traceback)")
        return 1
    return rc if isinstance(rc, int) else 0


if __name__ == "__main__":
    from demo.cli.main import main as _main  # the registered app lives in the imported module

    sys.exit(_main())
