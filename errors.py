"""The one error type the CLI turns into a one-line message."""

from __future__ import annotations

from pathlib import Path


class DemoError(Exception):
    """A problem the user can fix, naming the file (or object) it is about.

    The CLI prints ``error: <where>: <problem>`` on one line and exits non-zero; library callers
    catch it like any exception.
    """

    def __init__(self, where: str | Path | None, problem: str, exit_code: int = 1):
        self.where = str(where) if where is not None else None
        self.problem = problem
        self.exit_code = exit_code
        super().__init__(f"{self.where}: {problem}" if self.where else problem)

    def __reduce__(self) -> tuple:
        # Errors raised in worker processes travel back by pickle.
        return (DemoError, (self.where, self.problem, self.exit_code))
