"""Progress bars of the CLI: the one renderer of :mod:`demo.progress` ticks.

Every command that reports progress does ``with bars(enabled) as progress: library_call(...,
progress=progress)``. Bars go to stderr, one per stage, so ``--json -`` keeps stdout pure JSON;
each shows ``done/total``, elapsed and remaining time and the tick's ``fields`` as ``name value``
pairs; a tick's ``message`` is printed above the bars. The bars stay on screen when done, as a
record of how long each stage took, and are cleared when the command fails (its error is then the
one line it prints).

Where stderr is not a terminal (a log file, a pipe, a batch job), a live bar would show nothing until it
ends and then one line cut to 80 columns; there each stage is a plain line instead, printed at most once a
minute while it runs and once more when the command ends, unless its last line already said how it ended.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
import time
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


LOG_EVERY_S = 60.0  # off a terminal: a running stage's line at most this often (seconds)


@contextmanager
def bars(enabled: bool = True, log_every_s: float = LOG_EVERY_S) -> Iterator[Progress]:
    """A :data:`~demo.progress.Progress` callback drawing rich bars on stderr while the block runs.

    ``enabled=False`` yields :func:`~demo.progress.silent` (nothing drawn, nothing printed). Off a terminal
    the stages are plain lines, each at most every ``log_every_s`` seconds and once at the end.
    """
    if not enabled:
        yield silent
        return
    if not err_console.is_terminal:
        with _lines(log_every_s) as progress:
            yield progress
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


@dataclass
class _Stage:
    """What a plain line says of one stage: its counts, fields and clock (stopped when done reaches total)."""

    name: str
    started: float  # time.monotonic() of its first tick (seconds)
    printed: float  # ... and of its last line
    said: tuple[int, int | None, str] | None = None  # the counts and fields of the last line printed
    ended: float | None = None  # when done reached total
    done: int = 0
    total: int | None = None
    info: str = ""

    def state(self) -> tuple[int, int | None, str]:
        return self.done, self.total, self.info

    def line(self, now: float) -> str:
        self.said = self.state()
        elapsed = (now if self.ended is None else self.ended) - self.started
        parts = [self.name, f"{self.done}/{'?' if self.total is None else self.total}", _clock(elapsed)]
        if self.total and 0 < self.done < self.total:
            parts.append(f"eta {_clock(elapsed * (self.total - self.done) / self.done)}")
        if self.info:
            parts.append(self.info)
        return "  ".join(parts)


def _clock(seconds: float) -> str:
    return str(timedelta(seconds=int(seconds)))


@contextmanager
def _lines(log_every_s: float) -> Iterator[Progress]:
    """The progress callback for a non-terminal stderr: one plain, whole line per stage now and then."""
    stages: dict[str, _Stage] = {}

    def say(line: str) -> None:
        err_console.print(line, highlight=False, markup=False, soft_wrap=True)

    def progress(tick: Tick) -> None:
        if tick.message is not None:
            say(tick.message)
        if tick.done is None and tick.total is None and not tick.fields:
            return
        now = time.monotonic()
        stage = stages.setdefault(tick.stage, _Stage(tick.stage, started=now, printed=now))
        if tick.total is not None:
            stage.total = tick.total
        if tick.done is not None:
            stage.done = tick.done
        if tick.fields:
            stage.info = format_fields(tick.fields)
        if stage.total is not None and stage.done >= stage.total and stage.ended is None:
            stage.ended = now
        if now - stage.printed >= log_every_s:
            stage.printed = now
            say(stage.line(now))

    yield progress  # on an error nothing more is printed: its one line follows what was logged
    now = time.monotonic()
    for stage in stages.values():
        if stage.state() != stage.said:  # a line that would repeat the last one is left out
            say(stage.line(now))
