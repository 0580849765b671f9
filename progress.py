"""The one progress protocol of every long operation: a callback that receives :class:`Tick` s.

Library code (collect, convert, curate, train, interop) reports what it has done by calling
``progress(Tick(...))``; it never draws anything. The CLI turns ticks into rich bars
(:mod:`demo.cli.progress`); tests and Python callers pass nothing (:func:`silent`) or collect the
ticks in a list.

A stage is one bar: ticks with the same ``stage`` update it, a new ``stage`` starts another.
``done``/``total`` count the stage's units (episodes, frames, optimiser steps); ``fields`` are
named values shown beside the bar (``loss``, ``val``, ``success``, ``info``); ``message`` is a
line to print above the bars (e.g. a DAgger round's summary).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Tick:
    """One progress report of one stage."""

    stage: str  # the bar's label, e.g. "collect pick", "train bc"
    done: int | None = None  # units finished so far (None: unchanged)
    total: int | None = None  # units in all (None: unknown or unchanged)
    fields: Mapping[str, Any] = field(default_factory=dict)  # named values shown beside the bar
    message: str | None = None  # a line printed above the bars


Progress = Callable[[Tick], None]


def silent(tick: Tick) -> None:
    """The progress callback that ignores every tick (the library default)."""


def or_silent(progress: Progress | None) -> Progress:
    """``progress`` itself, or :func:`silent` when None."""
    return progress if progress is not None else silent
