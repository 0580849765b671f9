"""The rich progress bar of training runs (loss, validation loss, rollout success), or silence.

Shared by every algorithm: ``with TrainProgress(total, "bc", enabled) as bar: bar.update(step, loss=...)``.
Fields not yet known show as ``-``.
"""

from __future__ import annotations

from typing import Any

FIELDS = ("loss", "val", "success", "info")


class TrainProgress:
    def __init__(self, total: int, description: str, enabled: bool = True, completed: int = 0):
        self.enabled = enabled
        self.total, self.description, self.completed = total, description, completed
        self._progress: Any = None
        self._task: Any = None
        self.fields = {k: "-" for k in FIELDS}
        self.fields["info"] = ""

    def __enter__(self) -> "TrainProgress":
        if self.enabled:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            from demo.cli.output import console

            self._progress = Progress(
                TextColumn(f"[bold]{self.description}[/]"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("loss {task.fields[loss]}"),
                TextColumn("val {task.fields[val]}"),
                TextColumn("success {task.fields[success]}"),
                TextColumn("{task.fields[info]}"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=console,
            )
            self._progress.__enter__()
            self._task = self._progress.add_task("train", total=self.total, completed=self.completed, **self.fields)
        return self

    def update(self, completed: int | None = None, **fields: Any) -> None:
        for k, v in fields.items():
            self.fields[k] = f"{v:.4g}" if isinstance(v, float) else str(v)
        if self._progress is not None:
            kwargs = {} if completed is None else {"completed": completed}
            self._progress.update(self._task, **kwargs, **self.fields)

    def log(self, text: str) -> None:
        if self._progress is not None:
            self._progress.console.print(text, highlight=False)

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.__exit__(*exc)
            self._progress = None
