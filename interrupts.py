"""Ctrl-C and SIGTERM end a ``demo`` command, and within a bounded time.

A command run as a process (``demo ...``, ``python -m demo ...``) turns SIGINT into ``KeyboardInterrupt``
as Python does, and also arms a watchdog: if the process has not ended :data:`GRACE_S` seconds later
(an interrupted run still ending its workers, closing its progress bar or its store), the watchdog
prints every thread's stack to stderr and exits with status 1 (a hang is a bug to report, with those stacks). Nothing stored is at risk:
an episode store commits each episode whole (:mod:`demo.store`), so what was committed stays and
what was not is never half-written. The watchdog runs in C (:func:`faulthandler.dump_traceback_later`),
so it fires even where Python code is stuck holding the interpreter.

In-process calls of :func:`demo.cli.main.main` (tests, notebooks) install nothing: their process is
not ours to end.
"""

from __future__ import annotations

import faulthandler
import signal
import sys
from typing import Any

GRACE_S = 30.0  # an interrupted command's workers end within 5-10 s (demo.executor); this is far beyond

_installed = False


def install() -> None:
    """Arm the watchdog on SIGINT for the rest of this process (the main thread only: signals go there)."""
    global _installed
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not one of someone else's
        signal.signal(signal.SIGINT, interrupt)
    _installed = True


def interrupt(signum: int, frame: Any) -> None:
    """A signal handler: raise ``KeyboardInterrupt`` (the command ends as after Ctrl-C) and, in a
    process that :func:`install`-ed it, arm the watchdog once."""
    global _installed
    if _installed:
        _installed = False  # one watchdog per process: a second signal does not push it back
        faulthandler.dump_traceback_later(GRACE_S, exit=True, file=sys.__stderr__)
    raise KeyboardInterrupt
