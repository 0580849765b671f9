"""Progress bars of the CLI: the one renderer of :mod:`demo.progress` ticks.

Every command that reports progress does ``with bars(enabled) as progress: library_call(...,
progress=progress)``. Bars go to stderr, one per stage, so ``--json -`` keeps stdout pure JSON;
each shows ``done/total``, elapsed and remaining time and the tick's ``fields`` as ``name value``
pairs; a tick's ``message`` is printed above the bars. The bars stay on screen when done, as a
record of how long each stage took, and are cleared when the command fails (its error is then the
one line it prints).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, TaskID, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.progress import Progress as RichProgress

from demo.cli.output import err_console, fmt
from demo.progress import Progress, Tick, silent


def format_fields(fields: Mapping[str, Any]) -> str:
    """``name value`` pairs, two spaces apart; floats with 4 significant digits. The field ``info``
    is free text and shows without its name; empty values are left out."""
    parts = (fmt(value) if name == "info" else f"{name} {fmt(value)}" for name, value in fields.items() if value != "")
    return "  ".join(parts)


@contextmanager
def bars(enabled: bool = True) -> Iterator[Progress]:
    """A :data:`~demo.progress.Progress` callback drawing rich bars on stderr while the block runs.

    ``enabled=False`` yields :func:`~demo.progress.silent` (nothing drawn, nothing printed).
    """
    if not enabled:
        yield silent
        return
    columns = (TextColumn("[bold]{task.description}[/]"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn(), TextColumn("{task.fields[info]}"))
    # Started at the first bar, not on entry: a command that fails validation prints its error alone.
    live = RichProgress(*columns, console=err_console, transient=False)
    stages: dict[str, TaskID] = {}

    def progress(tick: Tick) -> None:
        if tick.message is not None:
            live.console.print(tick.message, highlight=False, markup=False, soft_wrap=True)
        if tick.done is None and tick.total is None and not tick.fields:
            return  # a message only: no bar for it
        if tick.stage not in stages:
            if not stages:
                live.start()
            stages[tick.stage] = live.add_task(tick.stage, total=tick.total, info="")
        update: dict[str, Any] = {}
        if tick.total is not None:
            update["total"] = tick.total
        if tick.done is not None:
            update["completed"] = tick.done
        if tick.fields:
            update["info"] = format_fields(tick.fields)
        live.update(stages[tick.stage], **update)

    try:
        yield progress
    except BaseException:
        if stages:  # on an error its one line stands alone: the bars are cleared, not kept
            live.live.transient = True
            live.live.stop()  # not live.stop(): that adds a blank line on a non-terminal
        raise
    if stages:
        live.stop()
