"""Shared output helpers: rich tables on the terminal, JSON to a file or stdout."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table
from rich.text import Text

from demo import jsonio

console = Console()
err_console = Console(stderr=True)


def warn(message: str) -> None:
    """``warning: MESSAGE`` on stderr, as one line whatever the terminal width (a Text, not markup:
    a path may hold brackets that rich would eat)."""
    err_console.print(Text.assemble(("warning:", "bold yellow"), " ", message), highlight=False, soft_wrap=True)


def write_json(obj: Any, path: str | Path | None) -> None:
    """Write JSON to ``path`` (atomically, :func:`demo.jsonio.write_json`); ``"-"`` prints it to
    stdout; None writes nothing."""
    if path is None:
        return
    if str(path) == "-":
        print(jsonio.dumps(obj))
        return
    jsonio.write_json(path, obj)


def table(title: str, columns: Sequence[str], rows: Iterable[Sequence[Any]]) -> Table:
    """A table with a header row of ``columns``."""
    t = Table(title=title, title_justify="left")
    for c in columns:
        t.add_column(c)
    for r in rows:
        t.add_row(*[fmt(v) for v in r])
    return t


def kv_table(title: str, rows: Iterable[tuple[str, Any]]) -> Table:
    """A two-column ``name | value`` table without a header row (there is nothing to name)."""
    t = Table(title=title, title_justify="left", show_header=False)
    t.add_column(style="bold")
    t.add_column()
    for name, value in rows:
        t.add_row(name, fmt(value))
    return t


def report_console(json_out: str | None) -> Console:
    """Where a command prints its tables: stderr when ``--json -`` puts the JSON on stdout, else stdout."""
    return err_console if json_out == "-" else console


def fmt(v: Any) -> str:
    """A table cell or progress field: floats with 4 significant digits, anything else as ``str``."""
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}"
    return str(v)
