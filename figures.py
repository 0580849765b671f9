"""Matplotlib for PNG files: the headless backend and one way to save a figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from demo.errors import DemoError, first_line
from demo.jsonio import replace_atomically


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no display needed); imported on first use."""
    import matplotlib  # deferred: heavy dependency (matplotlib), only where a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # deferred: after choosing the Agg backend

    return plt


def save_figure(fig: Any, path: str | Path, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` (parent folders made; staged and renamed, so a full disk leaves the previous
    figure, and names this file), close it and return the path."""
    path = Path(path)
    try:
        replace_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png"))
    except OSError as exc:
        raise DemoError(path, f"could not be written ({exc.strerror or first_line(exc)})") from None
    finally:
        pyplot().close(fig)
    return path
